"""The honest thermal physics of the bench's parts (issue 28, drivers/sim/thermal_physics.py):
each effect shows in the generated samples, is absent when switched off, and its draws are in
the truth. The parts are driven on the simulated clock (their `step`, a lockstep world)."""

from typing import Any

import numpy as np
import pytest

from drivers.sim.config import PartPhysicsConfig, PartSpec, SimConfig, ThermalPhysicsConfig
from drivers.sim.gyro import PartModel
from drivers.sim.population import resolve_part
from drivers.sim.world import World

QUIET = {"arw_deg_per_sqrt_h": 0.0, "bias_instability_deg_per_h": 0.0,
         "rrw_deg_per_h_per_sqrt_h": 0.0}
B_T = 0.01  # deg/s per C: the part's bias temperature coefficient
NONE = {"element_tau_s": 0.0, "element_tau_sigma_s": 0.0,
        "gradient_sigma_dps_per_c_per_min": 0.0, "hysteresis_dps": 0.0,
        "hysteresis_sigma_dps": 0.0, "socket_air_sigma_c": 0.0}
DT = 0.005  # the part's sample period at 200 Hz


def _part(serial: str = "SIM-THERM", **thermal: Any) -> PartModel:
    """A noiseless part whose sensor follows the air at once (die lag 1 ms, no self-heating):
    the air's path is the sensor's, so only the element's physics lies between."""
    spec = PartSpec(socket=1, serial=serial, bias_dps=1.0, scale=1.0,
                    bias_temp_coeff_dps_per_c=B_T, scale_temp_coeff_per_c=0.0,
                    bias_supply_coeff_dps_per_v=0.0, scale_supply_coeff_per_v=0.0, **QUIET)
    thermal_cfg = ThermalPhysicsConfig(**{"mode": "honest", **NONE, **thermal})
    physics = PartPhysicsConfig(die_tau_s=1e-3, self_heat_c_per_w=0.0, thermal=thermal_cfg)
    return PartModel(resolve_part(spec), physics, seed=0, t_s=0.0, air_c=25.0)


def _drive(part: PartModel, t0: float, t1: float, air: Any) -> None:
    """World steps of 1 s from t0 to t1, the air a function of time."""
    for t in np.arange(t0 + 1.0, t1 + 0.5, 1.0):
        part.step(float(t), 1.0, float(air(t)), 5.0)


def _rate_output(part: PartModel, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(output at zero rate deg/s, reported sensor temperature C) at times `t`."""
    zero = np.zeros_like(t)
    return part.raw_output_dps(t, zero, zero, 5.0, DT)


def _step_response(part: PartModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A sensor step 25 -> 35 C at t = 1 s; (times, element C seen in the output, sensor C)."""
    _drive(part, 0.0, 1.0, lambda t: 35.0)
    part.step(400.0, 399.0, 35.0, 5.0)
    t = 1.0 + np.arange(0, 120.0, DT)
    y, sensor = _rate_output(part, t)
    return t, 25.0 + (y - 1.0) / B_T, sensor


def test_a_sensor_step_shows_the_element_lagging_with_its_drawn_time_constant() -> None:
    part = _part(element_tau_s=20.0, element_tau_sigma_s=5.0)
    tau = part.truth()["thermal"]["element_tau_s"]
    assert tau != 20.0 and 5.0 < tau < 40.0  # drawn from the spread, not the typical value
    t, element, sensor = _step_response(part)
    assert sensor == pytest.approx(35.0, abs=1e-9)  # the part reports its sensor: stepped
    gap = 35.0 - element
    assert gap[0] > 9.0  # the element starts about 10 C behind
    fitted = -1.0 / np.polyfit(t - t[0], np.log(gap), 1)[0]
    assert fitted == pytest.approx(tau, rel=1e-6)


def test_with_the_physics_off_the_element_is_the_sensor() -> None:
    for part in (_part(), _part(element_tau_s=20.0, mode="ideal")):
        _, element, sensor = _step_response(part)
        assert part.truth()["thermal"] is None
        assert element == pytest.approx(sensor, abs=1e-9)


def test_the_element_is_exact_whatever_the_sample_blocks() -> None:
    """One block or many: the same samples (the closed form, no per-block drift)."""
    t = 1.0 + np.arange(0, 60.0, DT)
    one, many = _part(element_tau_s=20.0), _part(element_tau_s=20.0)
    for part in (one, many):
        _drive(part, 0.0, 1.0, lambda s: 35.0)
        part.step(100.0, 99.0, 35.0, 5.0)
    y_one, _ = _rate_output(one, t)
    y_many = np.concatenate([_rate_output(many, blk)[0] for blk in np.array_split(t, 37)])
    assert y_many == pytest.approx(y_one, abs=1e-12)


def _ramp_bias(part: PartModel, rate_c_per_min: float) -> float:
    """The output's excess over the static temperature law at the end of a 10-min ramp."""
    _drive(part, 0.0, 600.0, lambda t: 25.0 + rate_c_per_min * t / 60.0)
    t = np.arange(590.0, 600.0, DT)
    y, sensor = _rate_output(part, t)
    return float(np.mean(y - (1.0 + B_T * (sensor - 25.0))))


def test_a_ramp_shows_the_rate_proportional_bias() -> None:
    part = _part(gradient_sigma_dps_per_c_per_min=0.004)
    g = part.truth()["thermal"]["gradient_dps_per_c_per_min"]
    assert g != 0.0
    assert _ramp_bias(part, 3.0) == pytest.approx(g * 3.0, rel=1e-9)
    assert _ramp_bias(_part(gradient_sigma_dps_per_c_per_min=0.004), -3.0) == pytest.approx(
        -g * 3.0, rel=1e-9)
    assert _ramp_bias(_part(), 3.0) == pytest.approx(0.0, abs=1e-12)  # off: none


def test_on_a_ramp_the_lagging_element_reads_rate_times_tau_behind() -> None:
    part = _part(element_tau_s=30.0)
    excess = _ramp_bias(part, 3.0)  # element = sensor - r tau: bias B_T lower
    assert excess == pytest.approx(-B_T * 3.0 / 60.0 * 30.0, rel=1e-6)


def _settled_bias(part: PartModel, path: list[float]) -> float:
    """Walk the air through `path` (1 C/s between points), hold 30 s, give the bias."""
    t, now = 0.0, 25.0
    for target in path:
        steps = int(abs(target - now))
        for k in range(1, steps + 1):
            t += 1.0
            part.step(t, 1.0, now + np.sign(target - now) * k, 5.0)
        now = target
    part.step(t + 30.0, 30.0, now, 5.0)
    times = np.arange(t + 29.0, t + 30.0, DT)
    y, sensor = _rate_output(part, times)
    return float(np.mean(y - (1.0 + B_T * (sensor - 25.0))))


def test_heating_and_cooling_to_one_temperature_differ_by_the_hysteresis() -> None:
    spread: dict[str, Any] = {"hysteresis_dps": 0.02, "hysteresis_sigma_dps": 0.005,
                              "hysteresis_width_c": 1.0}
    heated = _part(**spread)
    h = heated.truth()["thermal"]["hysteresis_dps"]
    assert h != 0.02 and h > 0
    up = _settled_bias(heated, [40.0])
    down = _settled_bias(_part(**spread), [55.0, 40.0])
    assert up == pytest.approx(h / 2, rel=1e-9)
    assert down == pytest.approx(-h / 2, rel=1e-9)
    # a reversal smaller than the play's width switches part-way: smooth, not a jump
    half = _settled_bias(_part(**spread), [40.0, 39.0])
    assert half == pytest.approx(0.0, abs=1e-9)
    assert _settled_bias(_part(), [55.0, 40.0]) == pytest.approx(0.0, abs=1e-12)


def test_the_draws_are_per_serial_and_listed_in_the_truth() -> None:
    spread = {"element_tau_s": 20.0, "element_tau_sigma_s": 5.0,
              "gradient_sigma_dps_per_c_per_min": 0.004, "hysteresis_dps": 0.01,
              "hysteresis_sigma_dps": 0.004}
    a, again, b = _part("SIM-A", **spread), _part("SIM-A", **spread), _part("SIM-B", **spread)
    keys = {"element_tau_s", "gradient_dps_per_c_per_min", "hysteresis_dps",
            "hysteresis_width_c", "element_temp_c", "hysteresis_state"}
    assert keys <= set(a.truth()["thermal"])
    assert a.truth()["thermal"] == again.truth()["thermal"]
    assert a.truth()["thermal"]["element_tau_s"] != b.truth()["thermal"]["element_tau_s"]


def _world(mode: str, seed: int = 7) -> World:
    config = SimConfig.model_validate({
        "seed": seed,
        "parts": [{"socket": 1, "serial": "SIM-0001"}, {"socket": 2, "serial": "SIM-0002"}],
        "part_physics": {"thermal": {"mode": mode}},
    })
    return World(config, lockstep=True)


def test_two_sockets_in_one_load_read_different_air() -> None:
    world = _world("honest")
    world.advance_to(6 * 3600.0)  # six die time constants and more: settled on the air
    truth = world.truth()
    air = truth["chamber"]["air_c"]
    socks = [truth["sockets"][s] for s in ("1", "2")]
    offsets = [s["air_offset_c"] for s in socks]
    assert offsets[0] != offsets[1]
    assert truth["thermal_physics"]["mode"] == "honest"
    for sock, offset in zip(socks, offsets, strict=True):
        assert sock["die_temp_c"] == pytest.approx(air + offset, abs=1e-6)
    assert _world("honest").truth()["sockets"]["1"]["air_offset_c"] == offsets[0]  # per seed
    ideal = _world("ideal")
    ideal.advance_to(6 * 3600.0)
    socks = [ideal.truth()["sockets"][s] for s in ("1", "2")]
    assert [s["air_offset_c"] for s in socks] == [0.0, 0.0]
    assert socks[0]["die_temp_c"] == socks[1]["die_temp_c"]


def test_the_bench_draws_from_the_products_typical_spreads() -> None:
    """The sim's default spreads are the ones config/products/gyr130.yaml declares."""
    from pathlib import Path

    from procedures.loading.config import load_product

    root = Path(__file__).resolve().parents[2]
    product, _ = load_product(root / "config/products/gyr130.yaml")
    assert product.thermal_typical is not None
    sim = ThermalPhysicsConfig().model_dump()
    for key, value in product.thermal_typical.model_dump().items():
        assert sim[key] == value, key


def test_a_three_axis_part_follows_its_lagging_element_on_every_axis() -> None:
    from drivers.sim.config import ThreeAxisSpec
    from drivers.sim.gyro3 import PartModel3, resolve_three_axis

    coeff = (B_T, -B_T, 2 * B_T)
    three = ThreeAxisSpec(bias_dps=(0.0, 0.0, 0.0), bias_temp_coeff_dps_per_c=coeff,
                          accel_noise_mps2=0.0)
    spec = PartSpec(socket=1, serial="IMU-THERM", three_axis=three, **QUIET)
    thermal = ThermalPhysicsConfig(**{"mode": "honest", **NONE, "element_tau_s": 20.0})
    physics = PartPhysicsConfig(die_tau_s=1e-3, self_heat_c_per_w=0.0, thermal=thermal)
    part = PartModel3(resolve_part(spec), resolve_three_axis("IMU-THERM", three), physics,
                      seed=0, t_s=0.0, air_c=25.0)
    _drive(part, 0.0, 1.0, lambda t: 35.0)
    part.step(400.0, 399.0, 35.0, 5.0)
    t = np.array([21.0, 121.0])
    raw, sensor = part.raw_output3(t, np.zeros((2, 3)), np.zeros((2, 3)), 5.0, DT)
    assert sensor == pytest.approx([35.0, 35.0], abs=1e-9)
    element = part.element_temp_at(t)[1]
    assert 35.0 - element[0] == pytest.approx((35.0 - element[1]) * np.exp(100.0 / 20.0))
    for axis in range(3):  # each axis's bias follows the element, not the sensor
        assert raw[:, axis] == pytest.approx(coeff[axis] * (element - 25.0), abs=1e-9)


def test_the_control_channels_truth_lists_the_draws() -> None:
    from drivers.sim.launcher import launch_bench

    config = {"parts": [{"socket": 1, "serial": "SIM-0001"}, {"socket": 2, "serial": "SIM-0002"}],
              "part_physics": {"thermal": {"mode": "honest"}}}
    with launch_bench(config=config, lockstep=True) as bench:
        truth = bench.control.truth()
    assert truth["thermal_physics"]["mode"] == "honest"
    local = _world("honest", seed=0).truth()
    for sock in ("1", "2"):
        wire, here = truth["sockets"][sock], local["sockets"][sock]
        assert wire["air_offset_c"] == here["air_offset_c"]
        for key in ("element_tau_s", "gradient_dps_per_c_per_min", "hysteresis_dps"):
            assert wire["thermal"][key] == here["thermal"][key] != 0.0
