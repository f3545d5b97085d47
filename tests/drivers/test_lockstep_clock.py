"""The lockstep clock: station time moves only by the waits, in bounded steps, via the bench."""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from typing import Any

import pytest

from common.clock import LockstepClock


class FakeBench:
    def __init__(self) -> None:
        self.asked: list[float] = []

    def advance(self, t_s: float) -> Mapping[str, Any]:
        self.asked.append(t_s)
        return {"time_s": t_s, "seq": {"1": len(self.asked)}}


def test_time_moves_only_while_waiting_in_steps_of_at_most_max_step() -> None:
    bench = FakeBench()
    clock = LockstepClock(bench.advance, max_step_s=0.5)
    clock.start_at(10.0)
    time.sleep(0.02)  # wall time passes: station time does not
    assert clock.now_s() == 10.0
    clock.sleep_s(1.2)
    assert bench.asked == pytest.approx([10.5, 11.0, 11.2])
    assert clock.now_s() == pytest.approx(11.2)
    clock.sleep_s(0.0)
    clock.sleep_s(-1.0)
    assert len(bench.asked) == 3


def test_waiters_see_each_step_with_the_bench_reply_and_time_already_moved() -> None:
    bench = FakeBench()
    clock = LockstepClock(bench.advance, max_step_s=1.0)
    seen: list[tuple[float, float, Any]] = []

    def waiter(t_s: float, reply: Mapping[str, Any]) -> None:
        seen.append((t_s, clock.now_s(), reply["seq"]))

    clock.add_waiter(waiter)
    clock.sleep_s(2.0)
    assert seen == [(1.0, 1.0, {"1": 1}), (2.0, 2.0, {"1": 2})]
    clock.remove_waiter(waiter)
    clock.sleep_s(1.0)
    assert len(seen) == 2


def test_after_an_abort_a_wait_still_passes_in_one_step() -> None:
    bench = FakeBench()
    clock = LockstepClock(bench.advance, max_step_s=0.5)
    clock.interrupt()
    clock.sleep_s(30.0)
    assert bench.asked == [30.0]  # a driver's deadline loop ends; no sample is wanted now


def test_concurrent_sleepers_never_move_time_backwards() -> None:
    bench = FakeBench()
    clock = LockstepClock(bench.advance, max_step_s=0.25)
    threads = [threading.Thread(target=clock.sleep_s, args=(2.0,)) for _ in range(3)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert bench.asked == sorted(bench.asked)
    assert clock.now_s() >= 2.0


def test_a_wall_timeout_is_as_long_as_on_a_real_bench() -> None:
    clock = LockstepClock(FakeBench().advance)
    assert clock.speed == 1.0 and clock.wall_timeout_s(3.0) == 3.0
    with pytest.raises(ValueError, match="positive"):
        LockstepClock(FakeBench().advance, max_step_s=0.0)
