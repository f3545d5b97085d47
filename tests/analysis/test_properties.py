"""Property tests: the analysis holds its promises over whole families of inputs."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from procedures.analysis.allan import overlapping_adev
from procedures.analysis.rate_table import fit_rate_table
from procedures.analysis.stop_method import analyze_stop_method
from tests.analysis.synth import raised_cosine


@settings(max_examples=40, deadline=None)
@given(
    bias=st.floats(-10.0, 10.0),
    scale=st.floats(0.9, 1.1),
    fs=st.sampled_from([50.0, 100.0, 200.0]),
    noise=st.floats(0.0, 0.2),
    first_rest=st.floats(2.0, 6.0),
    gap=st.floats(2.0, 6.0),
    durations=st.tuples(st.floats(1.5, 5.0), st.floats(1.5, 5.0)),
    angle=st.floats(60.0, 120.0),
    seed=st.integers(0, 2**31),
)
def test_stop_method_finds_every_move_and_integrates_it(
    bias: float, scale: float, fs: float, noise: float, first_rest: float, gap: float,
    durations: tuple[float, float], angle: float, seed: int,
) -> None:
    rng = np.random.default_rng(seed)
    d1, d2 = durations
    start2 = first_rest + d1 + gap
    t = np.arange(0.0, start2 + d2 + 3.0, 1.0 / fs)
    profiles = (raised_cosine(t, first_rest, d1, angle), raised_cosine(t, start2, d2, -angle))
    y = bias + scale * sum(profiles) + (0.01 + noise) * rng.standard_normal(t.size)
    r = analyze_stop_method(t, y, angle)
    assert len(r.moves) == 2, r.warnings
    for move, sign, profile in zip(r.moves, (1, -1), profiles, strict=True):
        # the integration window holds the motion: what it leaves out is negligible
        inside = (t >= move.start_s) & (t <= move.end_s)
        assert abs(np.trapezoid(np.where(inside, 0.0, profile), t)) < 1e-4 * angle, move
        # measured angle agrees with the truth within its own uncertainty (5 sigma) plus
        # a hair for the samples of motion under the noise band
        assert abs(move.measured_angle_deg - sign * scale * angle) < (
            5 * move.u_measured_angle_deg + 1e-3 * angle), move
    assert r.scale_correction is not None and r.u_scale_correction is not None
    assert abs(r.scale_correction - 1 / scale) < 6 * r.u_scale_correction + 2e-5


@settings(max_examples=40, deadline=None)
@given(
    rates=st.lists(st.floats(1.0, 300.0), min_size=1, max_size=6, unique=True),
    neg=st.lists(st.floats(1.0, 300.0), min_size=1, max_size=6, unique=True),
    scale=st.floats(0.5, 2.0),
    bias=st.floats(-20.0, 20.0),
)
def test_rate_table_recovers_any_exact_line(
    rates: list[float], neg: list[float], scale: float, bias: float
) -> None:
    w = np.array(sorted(set(rates) | {-v for v in neg} | {0.0}))
    y = scale * w + bias
    fit = fit_rate_table(w, np.zeros(w.size), y, np.full(w.size, 1e-3), 300.0)
    assert abs(fit.scale - scale) < 1e-9 * scale
    assert abs(fit.bias_dps - bias) < 1e-8
    assert fit.nonlinearity_pct_fs < 1e-8
    assert abs(fit.asymmetry_ppm) < 1e-3


@settings(max_examples=25, deadline=None)
@given(offset=st.floats(-1e3, 1e3), gain=st.floats(1e-3, 1e3), seed=st.integers(0, 2**31))
def test_allan_deviation_ignores_offset_and_scales_with_gain(
    offset: float, gain: float, seed: int
) -> None:
    x = np.random.default_rng(seed).standard_normal(4096)
    base = overlapping_adev(x, 10.0).adev_dps
    moved = overlapping_adev(offset + gain * x, 10.0).adev_dps
    # offset + gain * x is rounded to eps * |offset| per sample, which is eps * |offset| /
    # gain relative to the signal (1e6 x eps at offset 1e3, gain 1e-3): the tolerance grows
    # with that ratio (a fixed 1e-8 failed about 1 run in 11 at 1.02e-8)
    rtol = 1e-9 + 256 * np.finfo(float).eps * abs(offset) / gain
    np.testing.assert_allclose(moved, gain * base, rtol=rtol)
