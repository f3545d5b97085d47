"""The world's physics seen the way the station sees it: through the twins' wire formats."""

import numpy as np
import pytest

from drivers.fixture_protocol import rate_code_to_dps, temp_code_to_c
from drivers.rate_table_map import Control, Mode, Reg, Status
from drivers.sim.launcher import launch_bench
from drivers.sim.stream_probe import StreamProbe, scpi

from .conftest import modbus_client, regs32, wait_until

PART = {
    "socket": 1,
    "serial": "SIM-PHYS",
    "bias_dps": 8.6,
    "scale": 1.0567,
    "bias_temp_coeff_dps_per_c": 0.01,
    "scale_temp_coeff_per_c": 0.0,
    "bias_supply_coeff_dps_per_v": 0.0,
    "scale_supply_coeff_per_v": 0.0,
    "supply_current_a": 0.025,
}


class _Recorder:
    """Collects decoded samples (wraps the probe's parser)."""

    def __init__(self, probe: StreamProbe) -> None:
        self.t: list[np.ndarray] = []
        self.rate: list[np.ndarray] = []
        self.temp: list[np.ndarray] = []
        inner = probe.parsers[0]
        outer = self

        class _P(type(inner)):  # type: ignore[misc]
            def feed(self, data):  # type: ignore[no-untyped-def]
                res = super().feed(data)
                outer.t.append(res.time_s)
                outer.rate.append(rate_code_to_dps(res.rate_code))
                outer.temp.append(temp_code_to_c(res.temp_code))
                return res

        probe.parsers[0] = _P()

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return np.concatenate(self.t), np.concatenate(self.rate), np.concatenate(self.temp)


def test_self_heating_after_power_on_and_rate_output_at_100dps() -> None:
    # the ideal thermal physics: the die at the chamber's air, the bias at the sensor's
    ideal = {"part_physics": {"thermal": {"mode": "ideal"}}}
    with launch_bench(config={"parts": [PART], **ideal}, speed=200) as bench:
        table = modbus_client(bench.endpoints.rate_table)
        table.write_register(Reg.CONTROL, Control.ENABLE, device_id=1)
        table.write_registers(Reg.MODE, [Mode.RATE, 0, 0, *regs32(100_000)], device_id=1)
        wait_until(
            lambda: bool(
                table.read_holding_registers(Reg.STATUS, count=1, device_id=1).registers[0]
                & Status.AT_RATE
            ),
            5.0,
            "the table at 100 deg/s",
        )
        scpi(bench.endpoints.supply, "VOLT 5.25", "CURR 0.2", "OUTP ON")
        with StreamProbe([bench.endpoints.duts[1]]) as probe:
            rec = _Recorder(probe)
            probe.stream(50, frames=int(50 * 400))  # 400 s of world time at 50 Hz
            t, rate, temp = rec.arrays()
        table.write_register(Reg.CONTROL, 0, device_id=1)
        table.close()
        truth = bench.control.truth()["sockets"]["1"]
    # self-heating from power-on: 40 C/W * V^2 * (25 mA / 5 V) = 5.5 C at 5.25 V, tau 90 s;
    # the die started at the 25 C ambient air, so it only self-heats
    since_on = t - truth["fixture_clock_offset_s"] - truth["power_on_s"]
    assert since_on[0] > 0
    amplitude = 40 * 5.25**2 * 0.005
    expected = 25.0 + amplitude * (1 - np.exp(-since_on / 90.0))
    assert float(np.abs(temp - expected).mean()) < 0.05
    assert temp[-200:].mean() - temp[:200].mean() > 0.5 * amplitude * np.exp(-since_on[0] / 90)
    assert truth["die_temp_c"] == pytest.approx(temp[-200:].mean(), abs=0.1)
    # output at 100 deg/s: scale * w + bias + bias_tc * (T - 25), T the die temperature
    late = t > 300
    model = 1.0567 * 100 + 8.6 + 0.01 * (temp[late] - 25.0)
    assert float(np.mean(rate[late] - model)) == pytest.approx(0.0, abs=0.02)
