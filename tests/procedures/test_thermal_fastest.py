"""The thermal step with chamber.strategy: fastest, in an in-process world on a simulated
clock (no sleeps): it settles every die sooner than `setpoint` under the unchanged criterion,
never commands beyond the chamber's limits nor lets a die past the product's maximum, and
leaves the chamber at the target on every exit path (also when aborted mid-overshoot)."""

from __future__ import annotations

import bisect
import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from drivers.errors import SetpointOutOfRange
from procedures.loading.config import ChamberConfig
from procedures.runtime.conditions import Condition
from procedures.runtime.results import Analysis
from procedures.runtime.run_context import Aborted
from procedures.steps.registry import Place
from procedures.steps.thermal import Stabilise, ThermalSettings
from procedures.thermal.thermal_control import PartThermal, learn_heat_final_c

SAMPLE_S = 0.5


class World:
    """A ramp-limited chamber, its air, and dies that lag the air and heat themselves."""

    def __init__(self, die_taus_s: list[float], heat_c_per_w: float = 40.0,
                 limits_c: tuple[float, float] = (-40.0, 125.0)) -> None:
        self.now_s = 0.0
        self.setpoint_c = 25.0
        self.ramp_c_per_min = 0.0
        self.ramped_c = self.air_c = 25.0
        self.running = True
        self.limits_c = limits_c
        self.writes: list[tuple[float, float]] = []
        self.taus = die_taus_s
        self.die_c = [25.0] * len(die_taus_s)
        self.heat_c = [0.0] * len(die_taus_s)
        self.heat_c_per_w = heat_c_per_w
        self.power_w = 0.11
        self.power_scale = [1.0] * len(die_taus_s)  # a part drawing more current heats more
        self.samples: list[list[tuple[float, float]]] = [[] for _ in die_taus_s]
        self.abort_at_s = math.inf

    # the chamber's driver surface
    def read_setpoint(self) -> float:
        return self.setpoint_c

    def set_setpoint(self, temp_c: float) -> None:
        if not self.limits_c[0] <= temp_c <= self.limits_c[1]:
            raise SetpointOutOfRange(f"{temp_c} C outside the limits", instrument="chamber")
        self.setpoint_c = temp_c
        self.writes.append((self.now_s, temp_c))

    def set_ramp_rate(self, c_per_min: float) -> None:
        self.ramp_c_per_min = c_per_min

    def setpoint_limits(self) -> tuple[float, float]:
        return self.limits_c

    def is_running(self) -> bool:
        return self.running

    def run(self) -> None:
        self.running = True

    def read_temperature(self) -> float:
        return self.air_c

    # physics
    def reading(self, i: int) -> float:
        return self.die_c[i] + self.heat_c[i]

    def advance(self, dt_s: float) -> None:
        end = self.now_s + dt_s
        while self.now_s < end - 1e-9:
            if self.now_s >= self.abort_at_s:
                raise Aborted("operator abort")
            h = min(SAMPLE_S, end - self.now_s)
            move = self.ramp_c_per_min / 60.0 * h
            self.ramped_c += max(-move, min(move, self.setpoint_c - self.ramped_c))
            self.air_c += (self.ramped_c - self.air_c) * (1 - math.exp(-h / 60.0))
            for i, tau in enumerate(self.taus):
                self.die_c[i] += (self.air_c - self.die_c[i]) * (1 - math.exp(-h / tau))
                target = self.heat_c_per_w * self.power_w * self.power_scale[i]
                self.heat_c[i] += (target - self.heat_c[i]) * (1 - math.exp(-h / 90.0))
            self.now_s += h
            for i in range(len(self.taus)):
                self.samples[i].append((self.now_s, self.reading(i)))


class Stream:
    def __init__(self, world: World, index: int) -> None:
        self.world, self.index = world, index

    def fixture_time(self, station_time_s: float) -> float:
        return station_time_s

    def window(self, start_s: float, end_s: float) -> dict[str, Any]:
        rows = self.world.samples[self.index]
        i0 = bisect.bisect_left(rows, (start_s, -math.inf))
        i1 = bisect.bisect_left(rows, (end_s, -math.inf))
        arr = np.array(rows[i0:i1], dtype=np.float64).reshape(-1, 2)
        return {"time_s": arr[:, 0], "temp_c": arr[:, 1]}


class _Parts(list[Any]):
    """The run's parts as the thermal step reads them: every one (the supply's load) and
    those still running."""

    def alive(self) -> list[Any]:
        return list(self)

    def require(self) -> None:
        return None

    drop = None


def context(world: World, strategy: str, max_part_c: float | None = 85.0,
            max_overshoot_c: float = 15.0, ramp_c_per_min: float = 5.0) -> Any:
    clock = SimpleNamespace(now_s=lambda: world.now_s)
    parts = [
        SimpleNamespace(socket=i + 1, alive=True, stream=Stream(world, i), conditions={},
                        record=SimpleNamespace(analysis=Analysis(), measurements=[]),
                        thermal=PartThermal())
        for i in range(len(world.taus))
    ]

    def set_supply(volts: float) -> None:
        world.power_w = volts * volts * 0.025 / 5.0
        world.advance(0.2)

    def environment() -> tuple[float, float, float]:  # each part draws power_w x its scale
        volts = math.sqrt(world.power_w * 5.0 / 0.025)
        return world.air_c, volts, sum(world.power_scale) * world.power_w / volts

    return SimpleNamespace(
        clock=clock,
        wait=SimpleNamespace(clock=clock, sleep=world.advance),
        instruments=SimpleNamespace(
            chamber=world,
            log_environment=environment,
            set_supply_voltage=set_supply,
        ),
        parts=_Parts(parts),
        records=SimpleNamespace(segment=lambda *a, **k: None, event=lambda *a, **k: None),
        procedure=SimpleNamespace(
            chamber=ChamberConfig(strategy=strategy, max_overshoot_c=max_overshoot_c,
                                  ramp_c_per_min=ramp_c_per_min)
        ),
        product=SimpleNamespace(
            die_tau_s=300.0, max_part_temperature_c=max_part_c, min_part_temperature_c=None,
            self_heating_c_per_w=40.0,
            self_heating_tau_s=90.0,
        ),
    )


def step(temp_c: float, supply_v: float, previous: Condition | None) -> Stabilise:
    settings = ThermalSettings(window_s=60, slope_c_per_min=0.1, band_c=0.2)
    return Stabilise(settings, Place(condition=Condition(temp_c, supply_v), previous=previous))


def settle(world: World, strategy: str, temp_c: float = 45.0, **kw: Any) -> float:
    ctx = context(world, strategy, **kw)
    s = step(temp_c, 5.25, Condition(25.0, 5.25))
    start = world.now_s
    s.setup(ctx)
    s.main(ctx)
    return world.now_s - start


def warmed(taus: list[float]) -> World:
    """Parts powered at 5.25 V and settled at 25 C."""
    world = World(taus)
    world.power_w = 5.25 * 5.25 * 0.025 / 5.0
    world.heat_c = [40.0 * world.power_w] * len(taus)
    return world


@pytest.mark.parametrize("taus", [[300.0], [240.0, 300.0, 360.0]])
def test_fastest_settles_every_die_sooner_than_setpoint(taus: list[float]) -> None:
    straight = settle(warmed(taus), "setpoint")
    world = warmed(taus)
    fast = settle(world, "fastest")
    assert fast < 0.8 * straight  # the slowest die governs: with a spread of lags it gains less
    assert max(sp for _, sp in world.writes) > 45.0  # it did overshoot
    assert world.setpoint_c == 45.0  # and measures at the target
    # the unchanged criterion judged every die on its own reading: all near their final value
    for i in range(len(taus)):
        assert abs(world.reading(i) - (45.0 + world.heat_c[i])) < 0.6


def test_never_beyond_the_limits_nor_the_part_maximum() -> None:
    world = warmed([300.0, 200.0])
    world.limits_c = (-40.0, 60.0)
    settle(world, "fastest", max_part_c=52.0)
    writes = [sp for _, sp in world.writes]
    assert max(writes) > 45.0 and all(sp <= 52.0 for sp in writes)  # chamber's and part's
    # the die's own reading (self-heating included: 50.5 C at the target) stays below 52 C
    assert max(r for s in world.samples for _, r in s) <= 52.0 + 0.05
    assert world.setpoint_c == 45.0

    world = warmed([300.0])
    world.limits_c = (-40.0, 47.0)  # the chamber's own limit is the lower one here
    settle(world, "fastest", max_part_c=85.0)
    assert max(sp for _, sp in world.writes) <= 47.0


def test_a_target_beyond_the_part_maximum_is_refused_with_the_setting_to_check() -> None:
    world = warmed([300.0])
    with pytest.raises(SetpointOutOfRange, match="max_part_temperature_c"):
        settle(world, "fastest", max_part_c=40.0)
    assert world.setpoint_c == 25.0  # nothing was commanded


def test_an_abort_during_the_overshoot_leaves_the_chamber_at_the_target() -> None:
    world = warmed([300.0])
    world.abort_at_s = 360.0  # past the ramp to 45 C (240 s): the profile is beyond it
    with pytest.raises(Aborted):
        settle(world, "fastest")
    overshoot = [sp for t, sp in world.writes if t < 360.0]
    assert overshoot and max(overshoot) > 45.0
    assert world.setpoint_c == 45.0 and world.writes[-1][1] == 45.0


def test_setpoint_strategy_commands_the_target_only() -> None:
    world = warmed([300.0])
    settle(world, "setpoint")
    assert [sp for _, sp in world.writes] == [45.0]


def test_cooling_waits_for_the_air_before_judging_the_dies() -> None:
    world = warmed([300.0])
    world.air_c = world.ramped_c = world.setpoint_c = 45.0
    world.die_c = [45.0]
    # straight down (no overshoot) on a slow ramp: the die barely moves in the first window
    ctx = context(world, "fastest", max_overshoot_c=0.0, ramp_c_per_min=0.5)
    s = step(25.0, 5.25, Condition(45.0, 5.25))
    s.setup(ctx)
    s.main(ctx)
    # a die that had not started to move was not taken as stable: it reached the cold side
    assert world.reading(0) < 25.0 + world.heat_c[0] + 0.6
    assert world.setpoint_c == 25.0


def test_a_supply_change_settles_sooner_with_the_planned_profile() -> None:
    """At one temperature the self-heating step of a supply change is the whole wait: the
    linear programme's profile dips the air against it (one overshoot cannot shape it)."""

    def at_4v75() -> World:
        world = warmed([300.0])
        world.power_w = 4.75 * 4.75 * 0.025 / 5.0
        world.heat_c = [40.0 * world.power_w]
        return world

    def run(world: World, strategy: str) -> tuple[float, Any]:
        ctx = context(world, strategy)
        s = step(25.0, 5.25, Condition(25.0, 4.75))
        start = world.now_s
        s.setup(ctx)
        s.main(ctx)
        return world.now_s - start, s

    straight, _ = run(at_4v75(), "setpoint")
    world = at_4v75()
    fast, s = run(world, "fastest")
    assert fast < 0.75 * straight
    assert min(sp for _, sp in world.writes) < 25.0  # the air was dipped against the heating
    assert world.setpoint_c == 25.0
    assert s._control.summary(1)["plan"] == "profile"
    assert abs(world.reading(0) - (25.0 + world.heat_c[0])) < 0.2


def test_each_part_learns_its_own_self_heating_from_its_rise_at_power_on() -> None:
    """Parts drawing different currents heat differently; the supply tells only the load's
    total. Each part's heating is learned from its own sensor: within the power-on condition
    (the plan follows it) and, for the supply changes after it, as its own C/W."""
    world = World([300.0, 300.0, 300.0])
    world.power_scale = [0.8, 1.0, 1.25]
    ctx = context(world, "fastest")
    s = step(25.0, 4.75, None)  # the first condition: the parts were just powered
    s.setup(ctx)
    s.main(ctx)
    mean_scale = sum(world.power_scale) / 3
    learned = [p.thermal for p in ctx.parts.alive()]
    for i, part in enumerate(learned):
        assert part.excess_at_power_on_c is not None and part.c_per_w is None  # not yet
        assert abs(world.reading(i) - (25.0 + world.heat_c[i])) < 0.6
    # the supply change: each part's excess over the air at its start gives its own C/W
    world.advance(150.0)  # the measurements of the first condition
    s2 = step(25.0, 5.25, Condition(25.0, 4.75))
    s2.setup(ctx)
    s2.main(ctx)
    for i, part in enumerate(learned):
        truth = 40.0 * world.power_scale[i] / mean_scale
        assert part.c_per_w is not None and abs(part.c_per_w - truth) < 0.1 * truth
        assert abs(world.reading(i) - (25.0 + world.heat_c[i])) < 0.6
    assert learned[0].c_per_w < learned[1].c_per_w < learned[2].c_per_w


def test_a_sensor_offset_is_not_taken_for_self_heating() -> None:
    heating = PartThermal()
    heating.observe(1.5, 0.0, 40.0)  # just powered: the sensor reads 1.5 C over the air
    heating.observe(1.5 + 40.0 * 0.1, 0.1, 40.0)  # settled at 0.1 W: 4 C of heating
    assert heating.c_per_w == pytest.approx(40.0)
    heating.observe(1.5 + 400.0 * 0.1, 0.1, 40.0)  # a faulty sensor: held to 3 x the product
    assert heating.c_per_w == pytest.approx(120.0)


def test_the_heating_to_come_is_learned_from_the_rise_and_held_at_the_prediction_early() -> None:
    t = np.arange(0.0, 240.0, 5.0)
    rise = 4.5 + (0.2 - 4.5) * np.exp(-t / 90.0)  # the part tends to 4.5 C, predicted 4.0
    assert learn_heat_final_c(t, rise, 0.2, 4.0, 90.0) == pytest.approx(4.5, abs=0.1)
    early = t < 10.0  # two readings: the rise has hardly begun, the prediction stands
    assert learn_heat_final_c(t[early], rise[early], 0.2, 4.0, 90.0) == pytest.approx(4.0, abs=0.05)


def test_a_condition_starts_from_where_the_die_was_not_from_the_air() -> None:
    """A die judged stable may still creep: the next condition's start takes the die from
    the last condition's estimate, gone on towards the air, so the creep is not taken for
    self-heating."""
    thermal = PartThermal()
    assert thermal.die_now_c(100.0, 45.0) == 45.0  # nothing known: the air
    thermal.remember_die(44.7, at_s=100.0, tau_s=300.0)
    assert thermal.die_now_c(100.0, 45.0) == pytest.approx(44.7)
    assert thermal.die_now_c(400.0, 45.0) == pytest.approx(45.0 - 0.3 * math.exp(-1.0))
    thermal.remember_die(float("nan"), at_s=500.0, tau_s=300.0)  # no reading: kept
    assert thermal.die_lag_at_s == 100.0
