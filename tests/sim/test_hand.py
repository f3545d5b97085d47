"""The simulated operator's hand: a human move to the other stop after a prompt, read from
the station's prompts only (the bench's operator endpoint)."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.config import HandConfig
from drivers.sim.hand import HandFixture
from drivers.sim.launcher import launch_bench
from procedures.runtime.progress import ProgressEvent
from station.prompt_relay import PromptRelay
from tests.sim.conftest import wait_until

STOP_DEG = 90.03


def _rate_peaks(hand: HandFixture, start_s: float, end_s: float) -> int:
    r = hand.rate_dps(np.arange(start_s, end_s, 0.01))
    r = np.abs(r)
    return int(np.sum((r[1:-1] > r[:-2]) & (r[1:-1] >= r[2:]) & (r[1:-1] > 1.0)))


def test_a_prompt_turns_the_fixture_to_the_other_stop_after_a_reaction() -> None:
    cfg = HandConfig(bounce_probability=0.0)
    hand = HandFixture(cfg, STOP_DEG, seed=3, socket=1)
    move = hand.on_prompt(100.0)
    assert move is not None
    assert cfg.reaction_min_s <= move.start_s - 100.0 <= cfg.reaction_max_s
    assert cfg.move_min_s <= move.end_s - move.start_s <= cfg.move_max_s
    assert hand.angle_deg(move.start_s - 1e-6)[0] == 0.0
    assert hand.angle_deg(move.end_s + 0.01)[0] == pytest.approx(STOP_DEG, abs=1e-9)
    back = hand.on_prompt(move.end_s + 5.0)
    assert back is not None and back.to_deg == 0.0
    assert hand.angle_deg(back.end_s + 1.0)[0] == pytest.approx(0.0, abs=1e-9)
    # the rate integrates to the angle (what the part's samples carry)
    t = np.arange(99.0, back.end_s + 2.0, 0.001)
    travelled = np.cumsum(hand.rate_dps(t)) * 0.001
    assert travelled.max() == pytest.approx(STOP_DEG, abs=0.05)


def test_moves_are_jerky_not_smooth() -> None:
    """Most moves have a velocity with more than one bump (overlapping sub-movements)."""
    hand = HandFixture(HandConfig(bounce_probability=0.0), STOP_DEG, seed=5, socket=2)
    bumpy = 0
    t = 0.0
    for _ in range(20):
        move = hand.on_prompt(t)
        assert move is not None
        bumpy += _rate_peaks(hand, move.start_s, move.end_s) > 1
        t = move.end_s + 2.0
    assert bumpy >= 10


def test_a_bounce_rebounds_off_the_stop_never_through_it_and_settles() -> None:
    hand = HandFixture(HandConfig(bounce_probability=1.0), STOP_DEG, seed=1, socket=1)
    move = hand.on_prompt(0.0)
    assert move is not None and move.bounce is not None
    t = np.arange(move.start_s, move.end_s + 2.0, 0.0005)
    angle = hand.angle_deg(t)
    assert angle.max() <= STOP_DEG + 1e-9
    after = angle[t > move.end_s]
    assert STOP_DEG - after.min() > 0.1  # it did come off the stop
    assert hand.angle_deg(move.end_s + 1.5)[0] == pytest.approx(STOP_DEG, abs=1e-3)


def test_a_configured_flick_over_ranges_the_part() -> None:
    hand = HandFixture(HandConfig(over_range_probability=1.0), STOP_DEG, seed=1, socket=1)
    move = hand.on_prompt(0.0)
    assert move is not None and move.flicked
    t = np.arange(move.start_s, move.end_s, 0.001)
    assert np.abs(hand.rate_dps(t)).max() > 250.0  # beyond the GYR-130's range


def test_an_operator_who_does_not_respond_leaves_the_fixture() -> None:
    hand = HandFixture(HandConfig(responds=False), STOP_DEG, seed=1, socket=1)
    assert hand.on_prompt(0.0) is None
    assert hand.angle_deg(100.0)[0] == 0.0 and hand.prompts_seen == 1


def test_bench_without_a_table_turns_a_fixture_on_the_station_prompt() -> None:
    """The bench serves no rate table; the station's prompt, written to the operator
    endpoint as the station writes it, is the only thing that moves the fixture."""
    config = {
        "instruments": {"rate_table": "none"},
        "parts": [{"socket": 1, "serial": "SIM-H001"}, {"socket": 2, "serial": "SIM-H002"}],
    }
    with launch_bench(config=config, speed=100) as bench:
        assert bench.endpoints.rate_table == ""
        operator = bench.endpoints.raw["operator"]
        relay = PromptRelay(operator)
        relay(ProgressEvent(kind="step", step="manual_stop"))  # not a prompt: not shown
        relay(
            ProgressEvent(
                kind="prompt",
                step="manual_stop",
                message="Turn socket 2's fixture by hand to the other stop",
                sockets={2: "PROMPT"},
            )
        )
        assert relay.sent == 1

        def turned() -> bool:
            hand = bench.control.truth()["sockets"]["2"]["hand"]
            return bool(hand["moves"]) and hand["angle_deg"] > 80.0

        wait_until(turned, 10.0, "socket 2's fixture to reach its other stop")
        truth = bench.control.truth()
        assert truth["sockets"]["1"]["hand"]["moves"] == []  # socket 1 was not prompted
        assert truth["operator"]["prompts"][0]["sockets"] == [2]
        relay.close()


def test_the_operator_reacts_from_when_the_prompt_was_shown_not_when_it_was_read() -> None:
    """A busy bench reads a prompt line late: the reaction counts from the station's stamp
    (the machine's monotonic clock), but no move starts before the world's present."""
    import json
    import time

    from drivers.sim.config import parse_sim_config
    from drivers.sim.operator_eyes import OperatorEyes
    from drivers.sim.world import World

    world = World(parse_sim_config({"parts": [{"socket": 1, "serial": "SIM-H003"}]}), 100.0)
    eyes = OperatorEyes(world)
    time.sleep(0.05)  # 5 world seconds
    shown = time.monotonic() - 0.02  # shown 2 world seconds before it is read
    eyes.read(json.dumps({"kind": "prompt", "sockets": {"1": "PROMPT"},
                          "monotonic_s": shown}).encode())
    move = world.sockets[1].hand.moves[-1]
    read_at, shown_at = eyes.seen[-1]["time_s"], eyes.seen[-1]["shown_s"]
    hand = world.config.hand
    assert shown_at <= read_at - 2.0 + 1e-6  # the station's stamp, not the reading
    assert move.start_s >= read_at  # never in the past: those samples are sent
    assert move.start_s >= shown_at + hand.reaction_min_s
    assert move.start_s <= max(read_at, shown_at + hand.reaction_max_s) + 1e-9
    eyes.read(b'{"kind": "prompt", "sockets": [1], "monotonic_s": "soon"}')  # not a time
    assert len(world.sockets[1].hand.moves) == 2
    eyes.read(b"not json")
    assert len(eyes.seen) == 2
