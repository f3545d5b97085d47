"""The bench's sample frames, byte for byte, are what they were before its speed-ups.

A fixed scenario (eight sockets, one part with every optional effect, rate plateaus, a
position move with a bounce, a stream restart at another rate, compensation on, uneven advance
steps as the station's clock makes them) is run on a lockstep world, and each socket's bytes
are hashed. The hashes in data/bench_frames_golden.json were written by the bench before it
was vectorised (`GYROCAL_REGEN_GOLDEN=1 pytest tests/sim/test_bench_frames_golden.py`
rewrites them: only do that for a change that is meant to change the physics).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import pytest

from drivers import fixture_protocol as fp
from drivers.chamber_map import Reg as ChamberReg
from drivers.rate_table_map import Reg
from drivers.sim.config import parse_sim_config
from drivers.sim.world import World

GOLDEN = Path(__file__).resolve().parent / "data" / "bench_frames_golden.json"
EFFECTS = {
    "k2_quadratic": {"k2_per_dps": 5.0e-6},
    "k3_cubic": {"k3_per_dps2": 2.0e-9},
    "scale_asymmetry": {"asymmetry": 0.002},
    "g_sensitivity_tilt": {"g_sens_dps_per_g": 0.012, "tilt_deg": 2.0, "phase_deg": 30.0},
    "sensor_lag": {"tau_s": 0.01},
    "warmup_drift": {"amplitude_dps": 0.3, "tau_s": 120.0},
}
# station-like advance steps: short table polls, then the thermal wait's 5 s steps
STEPS_S = [0.2, 0.2, 0.35, 1.0, 5.0, 5.0, 0.1, 0.25, 2.5, 5.0]


def _world() -> World:
    parts: list[dict[str, Any]] = [{"socket": s, "serial": f"SIM-G{s:03d}"} for s in range(1, 8)]
    parts.append({"socket": 8, "serial": "SIM-G008", "effects": EFFECTS})
    config = parse_sim_config(
        {
            "parts": parts,
            "fixture": {"sockets": 8},
            # the golden frames are the ideal bench's (before issue 28's thermal physics)
            "part_physics": {"thermal": {"mode": "ideal"}},
            "table": {"bounce": {"amplitude_deg": 0.02, "frequency_hz": 8.0, "decay_s": 0.3}},
        }
    )
    world = World(config, lockstep=True)
    for line in ("VOLT 5.0", "CURR 0.5", "OUTP ON"):
        world.supply.handle(line)
    world.chamber.write(int(ChamberReg.SETPOINT), 300)  # 30.0 C: the dies warm during the run
    world.chamber.write(int(ChamberReg.RUN), 1)
    return world


def _table(world: World, t_s: float, mode: int, rate_mdps: int, pos_mdeg: int) -> None:
    regs = world.table.registers(t_s)
    values = [1, mode, *_i32(pos_mdeg), *_i32(rate_mdps), *_i32(200_000), *_i32(0)]
    world.table.write(t_s, int(Reg.CONTROL), values, regs)


def _i32(value: int) -> list[int]:
    v = value & 0xFFFFFFFF
    return [v >> 16, v & 0xFFFF]


def _run(together: bool) -> dict[str, str]:
    """The scenario's bytes per socket; `together`: as the bench makes them, every socket's
    frames at once (`World.produce_all`), else socket by socket (`FixtureSocket.produce`)."""
    world = _world()
    out = {s: bytearray() for s in world.sockets}
    t = world.advance_to(1.0)
    for s, sock in world.sockets.items():
        out[s] += sock.handle_line("ODR 200" if s % 2 else "ODR 100", t)
        out[s] += sock.handle_line("START", t + 0.001 * s)
    actions = {
        2: lambda t: _table(world, t, 2, 100_000, 0),  # rate mode 100 deg/s
        5: lambda t: _table(world, t, 2, -200_000, 0),
        7: lambda t: _table(world, t, 1, 0, 90_000),  # trapezoid move with its bounce
        8: lambda t: _restart(world, out, t),
    }
    for round_ in range(3):
        for i, step_s in enumerate(STEPS_S):
            t = world.advance_to(world.now_s() + step_s)
            if together:
                for s, frames in world.produce_all(t).items():
                    out[s] += frames
            else:
                for s, sock in world.sockets.items():
                    out[s] += sock.produce(t)
            if round_ == 0 and i in actions:
                actions[i](t)
    for s, sock in world.sockets.items():
        out[s] += sock.handle_line("STOP", world.advance_to(world.now_s() + 0.05))
    return {str(s): hashlib.sha256(bytes(data)).hexdigest() for s, data in out.items()}


def _restart(world: World, out: dict[int, bytearray], t_s: float) -> None:
    """Socket 3 restarts at 1 kHz; socket 8 gets calibration registers and compensation."""
    s3 = world.sockets[3]
    out[3] += s3.handle_line("STOP", t_s)
    out[3] += s3.handle_line("ODR 1000", t_s)
    out[3] += s3.handle_line("START", t_s)
    s8 = world.sockets[8]
    out[8] += s8.handle_line("CAL bias=0.5 scale=1.01 bias_tc=0.001 t0=25 v0=5", t_s)
    out[8] += s8.handle_line("COMP 1", t_s)


@pytest.mark.parametrize("together", [False, True], ids=["per-socket", "all-sockets"])
def test_bench_frames_are_byte_identical_to_the_golden_run(together: bool) -> None:
    hashes = _run(together)
    if os.environ.get("GYROCAL_REGEN_GOLDEN") == "1":
        GOLDEN.parent.mkdir(exist_ok=True)
        GOLDEN.write_text(json.dumps(hashes, indent=1, sort_keys=True) + "\n")
    golden = json.loads(GOLDEN.read_text())
    assert hashes == golden


def test_the_scenario_streams_every_socket() -> None:
    """The golden comparison means something: every socket sent frames, with motion in them."""
    world = _world()
    t = world.advance_to(1.0)
    sock = world.sockets[1]
    sock.handle_line("START", t)
    _table(world, t, 2, 100_000, 0)
    t = world.advance_to(3.0)
    res = fp.FrameParser().feed(sock.produce(t))
    assert res.seq.size == 400
    assert res.encoder[-1] - res.encoder[0] > 0  # the table turned under the samples
