"""The simulated bench's world: one clock at a speed factor, and every instrument's physics.

World time = wall time since start x speed, or in lockstep the time the station's clock last
asked for (`advance_to`). The world is advanced lazily (`advance()`) on
every request and by the bench's tick, with exact exponential steps for the slow thermal
states; the table's motion is analytic and evaluated at any time.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivers import fixture_protocol as fp
from drivers.rate_table_map import Fault
from drivers.sim.chamber import ChamberModel
from drivers.sim.config import PartSpec, SimConfig
from drivers.sim.fixture import FixtureSocket, SampleFields
from drivers.sim.gyro import PartModel
from drivers.sim.gyro3 import PartModel3, resolve_three_axis
from drivers.sim.population import resolve_part
from drivers.sim.supply import SupplyModel
from drivers.sim.table import TableModel
from drivers.sim.thermal_physics import socket_air_offset_c

SAFE_CHAMBER_RANGE_C = (10.0, 40.0)


class World:
    def __init__(
        self, config: SimConfig, speed: float | None = None, lockstep: bool = False
    ) -> None:
        self.config = config
        # lockstep: world time moves only by advance_to() (the station's clock asks)
        self.lockstep = lockstep
        self._lockstep_t = 0.0
        self.speed = float(speed if speed is not None else config.speed)
        if not self.speed > 0:
            raise ValueError(f"speed must be positive, got {self.speed}")
        self._t0_wall = time.monotonic()
        self._last_t = 0.0
        rng = np.random.default_rng([config.seed, 1])
        self.table = TableModel(config.table)
        self.chamber = ChamberModel(config.chamber)
        self.supply = SupplyModel(config.supply, rng)
        fx = config.fixture
        self.sockets: dict[int, FixtureSocket] = {}
        for s in range(1, config.socket_count + 1):
            angle = fx.stop_angle_deg
            if angle is None:  # each fixture socket's stops, measured once: 90 +/- 0.05 deg
                angle = 90.0 + float(
                    np.random.default_rng([config.seed, s, 90]).uniform(-0.05, 0.05)
                )
            self.sockets[s] = FixtureSocket(
                self, s, angle, fx.stop_angle_uncertainty_deg, fx.clock_offset_s + 0.137 * s
            )
            # this fixture position's air (drivers/sim/thermal_physics.py): 0 when ideal
            self.sockets[s].air_offset_c = socket_air_offset_c(
                config.seed, s, config.part_physics.thermal
            )
        for spec in config.parts:
            self.load_part(spec)

    # ------------------------------------------------------------ time

    def now_s(self) -> float:
        if self.lockstep:
            return self._lockstep_t
        return (time.monotonic() - self._t0_wall) * self.speed

    def world_time_at(self, monotonic_s: float) -> float:
        """The world time at a reading of the machine's monotonic clock (any process); in
        lockstep the world does not follow the machine's clock: the present world time."""
        if self.lockstep:
            return self._lockstep_t
        return (monotonic_s - self._t0_wall) * self.speed

    def advance_to(self, t_s: float) -> float:
        """Lockstep: move world time to `t_s` (never backwards) and bring every state there."""
        if not self.lockstep:
            raise ValueError("advance_to needs a lockstep world (station bench --lockstep)")
        self._lockstep_t = max(self._lockstep_t, float(t_s))
        return self.advance()

    def advance(self) -> float:
        """Bring every slow state up to now; returns the world time."""
        t = max(self.now_s(), self._last_t)
        dt = t - self._last_t
        self.chamber.step(dt)
        self.supply.load_siemens = self._load_siemens()
        supply_v = self.supply.output_v()
        air = self.chamber.air_c
        for sock in self.sockets.values():
            if sock.part is not None:
                sock.part.step(
                    t, dt, air + sock.air_offset_c, supply_v if sock.part_present() else 0.0
                )
        self._last_t = t
        return t

    def produce_all(self, t_s: float) -> dict[int, bytes]:
        """Every streaming socket's sample frames due up to `t_s` (sockets with none left
        out): the same bytes as each socket's `produce(t_s)`, with the table's angle evaluated
        once, at every socket's sample times together (sorted, so the motion profile finds
        each time's piece in one search), and every single-axis socket's frames encoded in
        one call (a frame's bytes depend on its own fields only)."""
        due: list[tuple[FixtureSocket, NDArray[np.float64]]] = []
        for sock in self.sockets.values():
            times = sock.due_times(t_s)
            if times is not None:
                due.append((sock, times))
        if not due:
            return {}
        if len(due) == 1:
            sock, times = due[0]
            return {sock.socket: sock.frames_at(times, self.table.angle_deg(times))}
        every = np.concatenate([times for _, times in due])
        order = np.argsort(every, kind="stable")
        angle = np.empty_like(every)
        angle[order] = self.table.angle_deg(every[order])
        out: dict[int, bytes] = {}
        pending: list[tuple[FixtureSocket, SampleFields]] = []
        start = 0
        for sock, times in due:
            end = start + times.size
            fields = sock.sample_fields(times, angle[start:end])
            if isinstance(fields, bytes):
                out[sock.socket] = fields
            else:
                pending.append((sock, fields))
            start = end
        for sock, frames in _encode_together(pending):
            out[sock.socket] = sock.finish_frames(frames)
        return {s.socket: out[s.socket] for s, _ in due}  # in socket order, as before

    def _load_siemens(self) -> float:
        g = 0.0
        for sock in self.sockets.values():
            part = sock.part
            if part is None or not sock.part_present():
                continue
            g += (
                1.0 / self.config.supply.short_resistance_ohm
                if part.shorted
                else part.conductance_s()
            )
        return g

    # ------------------------------------------------------------ operator actions

    def socket(self, index: int) -> FixtureSocket:
        if index not in self.sockets:
            raise KeyError(f"no socket {index}; this bench has sockets 1..{len(self.sockets)}")
        return self.sockets[index]

    def load_part(self, spec: PartSpec) -> FixtureSocket:
        sock = self.socket(spec.socket)
        t = self.advance()
        if spec.three_axis is None:
            sock.part = PartModel(
                resolve_part(spec), self.config.part_physics, self.config.seed, t,
                self.chamber.air_c + sock.air_offset_c,
            )
        else:  # a three-axis part in its cube (drivers/sim/gyro3.py)
            three = resolve_three_axis(spec.serial, spec.three_axis)
            sock.part = PartModel3(
                resolve_part(spec), three, self.config.part_physics, self.config.seed, t,
                self.chamber.air_c + sock.air_offset_c,
            )
        sock.streaming = False
        sock.absent = False
        self.advance()
        return sock

    def unload_part(self, index: int) -> None:
        sock = self.socket(index)
        self.advance()
        sock.part = None
        sock.streaming = False
        self.advance()

    # ------------------------------------------------------------ faults inside the world

    def trip_table(self, fault: Fault) -> None:
        self.table.inject_fault(self.advance(), fault)

    def set_interlock(self, open_: bool) -> None:
        self.table.set_interlock(self.advance(), open_)

    def clear_world_faults(self) -> None:
        self.advance()
        self.table.clear_faults()
        self.chamber.stuck = False
        self.chamber.stuck_reports_fault = False
        for sock in self.sockets.values():
            sock.absent = sock.part_silent = sock.fixture_silent = False
            sock.corrupt_byte_rate = sock.drop_frame_rate = 0.0
            if sock.part is not None:
                sock.part.shorted = False
        self.advance()

    # ------------------------------------------------------------ truth

    def safe_summary(self, t_s: float) -> dict[str, Any]:
        lo, hi = SAFE_CHAMBER_RANGE_C
        table_safe = self.table.is_safe(t_s)
        supply_off = not self.supply.output_on
        chamber_safe = self.chamber.is_safe(lo, hi)
        return {
            "table_stopped_and_disabled": table_safe,
            "supply_off": supply_off,
            "chamber_safe": chamber_safe,
            "all": table_safe and supply_off and chamber_safe,
        }

    def truth(self) -> dict[str, Any]:
        t = self.advance()
        return {
            "time_s": t,
            "speed": self.speed,
            "thermal_physics": self.config.part_physics.thermal.model_dump(),
            "table": self.table.truth(t),
            "chamber": self.chamber.truth(),
            "supply": self.supply.truth(),
            "sockets": {str(i): s.truth() for i, s in self.sockets.items()},
            "safe": self.safe_summary(t),
        }


def _encode_together(
    pending: list[tuple[FixtureSocket, SampleFields]],
) -> list[tuple[FixtureSocket, bytes]]:
    """Each socket's encoded sample frames, from one `fp.encode_samples` call over all of
    them (a socket without encoder counts gets 0 there, as its own call would)."""
    if not pending:
        return []
    if len(pending) == 1:
        sock, fields = pending[0]
        return [(sock, fp.encode_samples(*fields))]
    sizes = [f[0].size for _, f in pending]
    seq, time_us, rate, temp, status = (
        np.concatenate([f[i] for _, f in pending]) for i in range(5)
    )
    encoders = [f[5] for _, f in pending]
    encoder = None
    if any(e is not None for e in encoders):
        encoder = np.concatenate(
            [
                np.zeros(n, dtype=np.int64) if e is None else e
                for e, n in zip(encoders, sizes, strict=True)
            ]
        )
    frames = fp.encode_samples(seq, time_us, rate, temp, status, encoder)
    out: list[tuple[FixtureSocket, bytes]] = []
    start = 0
    for (sock, _), n in zip(pending, sizes, strict=True):
        end = start + n * fp.SAMPLE_FRAME_SIZE
        out.append((sock, frames[start:end]))
        start = end
    return out
