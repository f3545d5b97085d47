from __future__ import annotations

import numpy as np
import pytest

from drivers.protocols import SampleStatus
from procedures.analysis.errors import AnalysisError
from procedures.analysis.stop_method import StopMethodSettings, analyze_stop_method
from tests.analysis.synth import article_record, raised_cosine


def test_article_worked_example_numbers() -> None:
    t, y = article_record(np.random.default_rng(0))
    r = analyze_stop_method(t, y, reference_angle_deg=90.0)
    assert round(r.bias_correction_dps, 1) == -8.6
    assert [round(m.require_scale_correction(), 3) for m in r.moves] == [0.946, 0.944]
    assert round(r.require_scale_correction(), 3) == 0.945
    # integration brackets the motion (4.5-8 s, 12.5-16 s) as the article's 4-9 s, 12-16 s
    (m1, m2) = r.moves
    assert 4.0 < m1.start_s < 4.5 and 8.0 < m1.end_s < 9.0
    assert 12.0 < m2.start_s < 12.5 and 16.0 < m2.end_s < 16.5
    assert m1.direction == 1 and m2.direction == -1
    assert r.warnings == ()


def test_bias_window_is_the_first_static_window() -> None:
    t, y = article_record(np.random.default_rng(1))
    y = y + np.where(t > 10.0, 0.5, 0.0)  # a later bias shift must not enter the bias
    r = analyze_stop_method(t, y)
    assert r.bias_dps == pytest.approx(8.6, abs=0.01)
    assert r.bias.duration_s == pytest.approx(r.moves[0].start_s, abs=0.02)


def test_bounce_at_the_stop_stays_inside_one_move() -> None:
    rng = np.random.default_rng(2)
    t, y = article_record(rng, bounce_deg=0.5)  # up to 10 deg/s of rebound
    r = analyze_stop_method(t, y)
    assert len(r.moves) == 2
    assert r.moves[0].end_s > 8.5  # the bounce after arrival at 8 s is integrated
    assert abs(r.moves[0].measured_angle_deg - 95.1) < 4 * r.moves[0].u_measured_angle_deg
    # without the hold-off the same bounce would split the move (so the test can fail)
    split = analyze_stop_method(t, y, settings=StopMethodSettings(min_static_s=0.0))
    assert len(split.moves) + len(split.warnings) > 2


def test_k2_intervals_of_the_scale_cover_93_to_97_percent() -> None:
    rng = np.random.default_rng(3)
    fs, scale, angle, u_ref = 50.0, 1.0567, 90.0, 0.05
    t = np.arange(0.0, 21.0, 1.0 / fs)
    motion = raised_cosine(t, 4.5, 3.5, angle) + raised_cosine(t, 12.5, 3.5, -angle)
    trials = 1000
    hits = np.zeros(3, dtype=int)
    for _ in range(trials):
        y = 8.6 + scale * motion + 0.1 * rng.standard_normal(t.size)
        ref = angle + u_ref * rng.standard_normal()  # the inclinometer's own error
        r = analyze_stop_method(t, y, ref, u_ref)
        assert r.scale_correction is not None and r.u_scale_correction_k2 is not None
        hits[0] += abs(r.scale_correction - 1 / scale) <= r.u_scale_correction_k2
        for k, m in enumerate(r.moves):
            assert m.scale_correction is not None and m.u_scale_correction is not None
            hits[1 + k] += abs(m.scale_correction - 1 / scale) <= 2 * m.u_scale_correction
    cover = hits / trials
    assert np.all((cover >= 0.93) & (cover <= 0.97)), cover


def test_over_range_move_is_refused_and_flagged() -> None:
    t, y = article_record(np.random.default_rng(4))
    status = np.zeros(t.size, dtype=np.int64)
    status[(t > 6.0) & (t < 6.1)] = int(SampleStatus.OVER_RANGE)
    r = analyze_stop_method(t, y, status=status)
    first, second = r.moves
    assert first.clipped and first.scale_correction is None
    assert not second.clipped and second.scale_correction is not None
    assert r.scale_correction == second.scale_correction
    assert r.n_over_range == int((status != 0).sum())
    (span,) = r.over_range_intervals_s
    assert 6.0 < span[0] <= span[1] < 6.1
    assert any("over-range" in w for w in r.warnings)


def test_full_scale_threshold_flags_clipping_without_status_bits() -> None:
    t, y = article_record(np.random.default_rng(5))
    r = analyze_stop_method(t, y, settings=StopMethodSettings(full_scale_dps=45.0))
    assert all(m.clipped for m in r.moves)
    with pytest.raises(AnalysisError, match="over-range"):
        r.require_scale_correction()


def test_record_starting_in_motion_is_refused() -> None:
    t, y = article_record(np.random.default_rng(6))
    keep = t > 5.0
    with pytest.raises(AnalysisError, match="at rest"):
        analyze_stop_method(t[keep], y[keep])


def test_station_window_beginning_in_the_tail_of_a_motion_is_trimmed_to_its_end() -> None:
    """The station's window can start a little early (station-to-fixture time mapping) and
    catch the end of the move to the first stop: with trim_leading_motion the record is used
    from the end of that motion, and the result equals the clean record's."""
    t, y = article_record(np.random.default_rng(6))
    tail = t < 1.0
    moving = y.copy()
    moving[tail] += 40.0 * (1.0 - t[tail])  # decelerating from 40 deg/s to rest in 1 s
    with pytest.raises(AnalysisError, match="at rest"):
        analyze_stop_method(t, moving)
    clean = analyze_stop_method(t[~tail], y[~tail])
    r = analyze_stop_method(t, moving, settings=StopMethodSettings(trim_leading_motion=True))
    assert len(r.moves) == 2
    assert r.require_scale_correction() == pytest.approx(clean.require_scale_correction(),
                                                         abs=2e-4)
    assert r.bias_dps == pytest.approx(clean.bias_dps, abs=0.01)
    assert any("began in motion" in w for w in r.warnings)
    # a record with no move after its leading motion is still refused
    early = t < 4.0
    with pytest.raises(AnalysisError, match="at rest"):
        analyze_stop_method(t[early], moving[early],
                            settings=StopMethodSettings(trim_leading_motion=True))


def test_record_without_motion_is_refused() -> None:
    t = np.arange(0, 20, 0.01)
    with pytest.raises(AnalysisError, match="no move"):
        analyze_stop_method(t, 8.6 + 0.02 * np.random.default_rng(7).standard_normal(t.size))


def test_record_ending_inside_a_move_gives_no_scale_for_it() -> None:
    t, y = article_record(np.random.default_rng(8))
    keep = t < 14.0
    r = analyze_stop_method(t[keep], y[keep])
    assert r.moves[-1].complete is False and r.moves[-1].scale_correction is None
    assert r.scale_correction == r.moves[0].scale_correction


def test_moves_filling_most_of_the_record_are_still_found() -> None:
    """Static only 35 % of the time: a plain median would sit inside a move."""
    rng = np.random.default_rng(9)
    t = np.arange(0.0, 16.0, 0.01)
    y = (8.6 + raised_cosine(t, 2.0, 5.0, 95.0) + raised_cosine(t, 8.0, 5.0, 95.0)
         + 0.05 * rng.standard_normal(t.size))
    assert abs(np.median(y) - 8.6) > 1.0
    r = analyze_stop_method(t, y)
    assert r.bias_dps == pytest.approx(8.6, abs=0.02)
    assert [round(m.measured_angle_deg) for m in r.moves] == [95, 95]
