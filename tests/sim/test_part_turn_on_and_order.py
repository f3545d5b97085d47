"""The world's part: turn-on bias offset at each power-on, temperature terms beyond first
order, and the part's compensation with higher-order registers; the sim fixture's registers."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.protocols import CalibrationRegisters
from drivers.sim.config import (
    FixtureConfig,
    PartPhysicsConfig,
    PartSpec,
    SimConfig,
    ThermalPhysicsConfig,
)
from drivers.sim.gyro import PartModel
from drivers.sim.population import resolve_part

QUIET = {"arw_deg_per_sqrt_h": 0.0, "bias_instability_deg_per_h": 0.0,
         "rrw_deg_per_h_per_sqrt_h": 0.0}
COEFFS = {"bias_dps": 1.5, "scale": 1.02, "bias_temp_coeff_dps_per_c": 0.01,
          "scale_temp_coeff_per_c": 2e-4, "bias_supply_coeff_dps_per_v": 0.05,
          "scale_supply_coeff_per_v": 1e-3}
HIGHER = {"bias_temp_coeff2_dps_per_c2": -2e-4, "bias_temp_coeff3_dps_per_c3": 3e-6,
          "scale_temp_coeff2_per_c2": -4e-6, "scale_temp_coeff3_per_c3": 6e-8}


def _part(air_c: float = 25.0, **extra: float) -> PartModel:
    spec = PartSpec(socket=1, serial="SIM-TURN", **{**QUIET, **COEFFS, **extra})
    physics = PartPhysicsConfig(thermal=ThermalPhysicsConfig(mode="ideal"))  # exact bias
    return PartModel(resolve_part(spec), physics, seed=0, t_s=0.0, air_c=air_c)


def _static_bias(part: PartModel, t_s: float) -> float:
    y, _ = part.raw_output_dps(np.array([t_s]), np.zeros(1), np.zeros(1), 5.0, 0.01)
    return float(y[0])


def _power_cycle(part: PartModel, t_s: float) -> None:
    part.step(t_s, 1.0, 25.0, 0.0)
    part.step(t_s + 1.0, 1.0, 25.0, 5.0)


def test_parts_configured_before_have_no_turn_on_offset_and_no_higher_terms() -> None:
    params = resolve_part(PartSpec(socket=1, serial="SIM-0001"))
    assert params.turn_on_bias_sigma_dps == 0.0 and params.bias_temp_coeff2_dps_per_c2 == 0.0
    part = _part()
    offsets = set()
    for k in range(5):
        _power_cycle(part, 10.0 * k)
        offsets.add(part.turn_on_bias_dps)
    assert offsets == {0.0} and part.power_on_count == 5


def test_each_power_on_draws_a_new_offset_with_the_parts_sigma() -> None:
    part = _part(turn_on_bias_sigma_dps=0.08, bias_temp_coeff_dps_per_c=0.0)  # no self-heating
    offsets, biases = [], []
    for k in range(400):
        _power_cycle(part, 10.0 * k)
        offsets.append(part.turn_on_bias_dps)
        biases.append(_static_bias(part, 10.0 * k + 1.0))
        assert part.truth()["turn_on_bias_dps"] == offsets[-1]
    assert np.std(offsets, ddof=1) == pytest.approx(0.08, rel=0.12)
    assert part.truth()["turn_on_history_dps"] == offsets[-256:]
    # the offset is what the bias moves by, and it holds while the part stays on
    assert np.allclose(np.array(biases) - np.array(offsets), biases[0] - offsets[0], atol=1e-12)
    part.step(10.0 * 400, 1.0, 25.0, 5.0)
    assert part.turn_on_bias_dps == offsets[-1]


def test_turn_on_offsets_are_the_same_for_the_same_serial_and_seed() -> None:
    a, b = _part(turn_on_bias_sigma_dps=0.1), _part(turn_on_bias_sigma_dps=0.1)
    for k in range(3):
        _power_cycle(a, 10.0 * k)
        _power_cycle(b, 10.0 * k)
        assert a.turn_on_bias_dps == b.turn_on_bias_dps != 0.0


@pytest.mark.parametrize("air_c", [-20.0, 60.0])
def test_third_order_terms_follow_the_design_formula(air_c: float) -> None:
    part = _part(air_c=air_c, **HIGHER)
    w = np.array([-100.0, 0.0, 200.0])
    y, die = part.raw_output_dps(np.zeros(3), w, np.zeros(3), 5.0, 0.01)
    dt = die - 25.0
    scale = 1.02 * (1 + 2e-4 * dt - 4e-6 * dt**2 + 6e-8 * dt**3)
    bias = 1.5 + 0.01 * dt - 2e-4 * dt**2 + 3e-6 * dt**3
    assert y == pytest.approx(scale * w + bias, abs=1e-12)


def test_higher_order_registers_compensate_a_higher_order_part() -> None:
    part = _part(air_c=70.0, **HIGHER)
    part.cal = CalibrationRegisters(
        bias_dps=1.5, scale=1.02, bias_tc_dps_per_c=0.01, scale_tc_per_c=2e-4,
        bias_vc_dps_per_v=0.05, scale_vc_per_v=1e-3, bias_tc2_dps_per_c2=-2e-4,
        bias_tc3_dps_per_c3=3e-6, scale_tc2_per_c2=-4e-6, scale_tc3_per_c3=6e-8,
    )
    w = np.array([-150.0, 0.0, 90.0])
    raw, die = part.raw_output_dps(np.zeros(3), w, np.zeros(3), 5.0, 0.01)
    assert part.compensate(raw, die, 5.0) == pytest.approx(w, abs=1e-9)
    first_only = CalibrationRegisters(**{
        k: v for k, v in vars(part.cal).items() if "tc2" not in k and "tc3" not in k})
    part.cal = first_only
    assert np.max(np.abs(part.compensate(raw, die, 5.0) - w)) > 0.1


def test_fixture_calibration_order_defaults_to_three_and_is_bounded() -> None:
    assert FixtureConfig().calibration_order == 3
    assert SimConfig.model_validate({"fixture": {"calibration_order": 1}}).fixture
    with pytest.raises(ValueError, match="calibration_order"):
        SimConfig.model_validate({"fixture": {"calibration_order": 4}})


def _socket(calibration_order: int | None = None):
    from drivers.sim.config import parse_sim_config
    from drivers.sim.world import World

    fixture = {} if calibration_order is None else {"calibration_order": calibration_order}
    w = World(parse_sim_config({"parts": [{"socket": 1, "serial": "SIM-CAL"}],
                                "fixture": fixture}), speed=1.0)
    for line in ("VOLT 5.0", "CURR 0.5", "OUTP ON"):
        w.supply.handle(line)
    w.advance()
    return w.sockets[1]


def _ask(sock, line: str) -> str:
    from drivers import fixture_protocol as fp

    return fp.FrameParser().feed(sock.handle_line(line, 1.0)).replies[0]


def test_sim_fixture_holds_third_order_registers_by_default() -> None:
    sock = _socket()
    keys = [kv.split("=")[0] for kv in _ask(sock, "CAL?")[3:].split()]
    assert keys == ["bias", "scale", "bias_tc", "scale_tc", "bias_vc", "scale_vc", "t0", "v0",
                    "bias_tc2", "bias_tc3", "scale_tc2", "scale_tc3"]
    assert _ask(sock, "CAL bias_tc2=-0.0002 scale_tc3=6e-08") == "OK"
    assert sock.part.cal.bias_tc2_dps_per_c2 == -0.0002
    assert sock.truth()["calibration"]["scale_tc3_per_c3"] == 6e-08


@pytest.mark.parametrize(("order", "refused"), [(1, "bias_tc2"), (2, "bias_tc3")])
def test_sim_fixture_of_lower_order_lists_and_takes_only_its_registers(order, refused) -> None:
    sock = _socket(order)
    reply = _ask(sock, "CAL?")
    assert (refused + "=") not in reply
    assert _ask(sock, f"CAL {refused}=0.001").startswith("ERR 4")
    assert _ask(sock, "CAL bias=1.0") == "OK"
