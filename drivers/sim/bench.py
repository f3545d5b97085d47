"""The simulated bench process: the world, its twins on loopback and ptys, the control channel.

`run_bench` runs until SIGINT/SIGTERM, writes the JSON state file of docs/interfaces.md once every
endpoint listens, and on exit shuts each Modbus server down, closes every pty and the
control channel, and leaves the state file (the user gave its path) in place.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import signal
import sys
import time
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from drivers.fixture_protocol import SEQ_MODULO
from drivers.rate_table_map import Fault
from drivers.sim.absent_twin import AbsentTwin
from drivers.sim.acutrol_twin import AcutrolTwin
from drivers.sim.config import PartSpec, SimConfig
from drivers.sim.control import ControlRequestError, ControlServer
from drivers.sim.espec_twin import EspecP300Twin
from drivers.sim.fixture_board import FixtureBoardTwin, board_sockets
from drivers.sim.inclinometer_twin import InclinometerTwin
from drivers.sim.modbus_twins import ChamberTwin, TableTwin
from drivers.sim.operator_eyes import OperatorEyes
from drivers.sim.pty_twins import FixtureTwin, SupplyTwin
from drivers.sim.scpi_lan_twins import KeysightE36300Twin, RigolDp800Twin
from drivers.sim.watlow_f4t_twin import WatlowF4TTwin
from drivers.sim.world import World

log = logging.getLogger(__name__)
TICK_WALL_S = 0.005  # while any socket streams
IDLE_TICK_WALL_S = 0.02  # thermal states only; every request advances the world anyway

FAULT_KINDS = (
    "modbus_drop",
    "modbus_delay",
    "table_fault",
    "interlock_open",
    "chamber_stuck",
    "supply_short",
    "stream_corrupt",
    "stream_drop",
    "part_silent",
    "fixture_silent",
    "part_absent",
)
_TABLE_FAULTS = {
    "following_error": Fault.FOLLOWING_ERROR,
    "estop": Fault.ESTOP,
    "overspeed": Fault.OVERSPEED,
    "encoder_loss": Fault.ENCODER_LOSS,
}


class SerialSupplyTwin:
    """Today's SCPI supply twin (a pseudo-terminal) in the bench's twin form: its endpoint is
    the pty path, the `supply.scpi` driver's address. Faults on it are injected per part
    (supply_short); drop/restore and delay_s are accepted and do nothing."""

    def __init__(self, world: World, host: str = "127.0.0.1", port: int = 0) -> None:
        self.world = world
        self.delay_s = 0.0
        self.twin: SupplyTwin | None = None

    async def start(self) -> None:
        self.twin = SupplyTwin(self.world, asyncio.get_running_loop())

    def endpoint(self) -> str:
        assert self.twin is not None, "start() the twin first"
        return self.twin.port.path

    async def drop(self) -> None:
        log.info("the serial supply twin cannot drop its pty; fault ignored")

    async def restore(self) -> None:
        return None

    async def shutdown(self) -> None:
        if self.twin is not None:
            self.twin.close()
            self.twin = None


# (role, family) -> twin class: Twin(world, host, port) with async start(), endpoint (a
# method, or a property as on the Modbus twins), async drop()/restore()/shutdown(), delay_s.
TWINS: dict[tuple[str, str], Any] = {
    ("rate_table", "modbus-servo"): TableTwin,
    ("rate_table", "acutrol"): AcutrolTwin,
    ("chamber", "watlow-f4"): ChamberTwin,
    ("chamber", "watlow-f4t"): WatlowF4TTwin,
    ("chamber", "espec-p300"): EspecP300Twin,
    ("supply", "scpi"): SerialSupplyTwin,
    ("supply", "keysight-e36300"): KeysightE36300Twin,
    ("supply", "rigol-dp800"): RigolDp800Twin,
    ("rate_table", "none"): AbsentTwin,
    ("inclinometer", "ascii-xy"): InclinometerTwin,  # one per socket: InclinometerTwin(world, s)
}


def twin_class(role: str, family: str) -> Any:
    """The twin class serving `family` for `role`; ValueError naming those there are."""
    try:
        return TWINS[(role, family)]
    except KeyError:
        served = ", ".join(f for r, f in TWINS if r == role)
        raise ValueError(
            f"the simulated bench has no {role} twin for {family!r} (it serves: {served}); "
            "choose another family under instruments: in the sim config"
        ) from None


def endpoint_of(twin: Any) -> str:
    """A twin's address in its driver's form (endpoint is a method or a property)."""
    ep = twin.endpoint
    return str(ep() if callable(ep) else ep)


class Bench:
    """Everything the bench process serves, on one asyncio loop."""

    def __init__(
        self,
        config: SimConfig,
        speed: float | None = None,
        host: str = "127.0.0.1",
        table_port: int = 0,
        chamber_port: int = 0,
        control_port: int = 0,
        lockstep: bool = False,
    ) -> None:
        self.world = World(config, speed, lockstep)
        self.host = host
        self.families = config.instruments.families()
        self.table: Any = twin_class("rate_table", self.families["rate_table"])(
            self.world, host, table_port
        )
        self.chamber: Any = twin_class("chamber", self.families["chamber"])(
            self.world, host, chamber_port
        )
        self.supply: Any = twin_class("supply", self.families["supply"])(self.world, host, 0)
        self.control = ControlServer(self.dispatch, host, control_port)
        self.eyes = OperatorEyes(self.world, host)  # the simulated operator reads prompts
        self.fixtures: dict[int, FixtureTwin] = {}  # every board's sockets
        self.boards: list[FixtureBoardTwin] = []
        self.inclinometers: dict[int, InclinometerTwin] = {}
        if config.instruments.inclinometer != "none":
            self.inclinometers = {
                s: InclinometerTwin(self.world, s, host) for s in self.world.sockets
            }
        self._tick_task: asyncio.Task[None] | None = None
        self.ticks = 0
        self.table.before_write = self._flush_samples

    def _flush_samples(self, t_s: float) -> None:
        """Send every sample due before a motion command, so none is computed with the new
        motion profile (the tick loop runs every few wall ms, seconds of world time at 100x)."""
        self._tick_fixtures(t_s)

    def _tick_fixtures(self, t_s: float) -> None:
        """Send every socket's sample frames due up to `t_s` (the table's angle evaluated
        once for all of them)."""
        frames = self.world.produce_all(t_s)
        if frames:
            for board in self.boards:
                board.send(frames)

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        await self.table.start()
        await self.chamber.start()
        await self.supply.start()
        fixture = self.world.config.fixture
        groups = board_sockets(list(self.world.sockets), fixture.sockets_per_board)
        for number, sockets in enumerate(groups, start=1):
            board = FixtureBoardTwin(self.world, number, sockets, loop, fixture.fifo_bytes)
            self.boards.append(board)
            self.fixtures.update(board.twins)
        await self.control.start()
        await self.eyes.start()
        for inclinometer in self.inclinometers.values():
            await inclinometer.start()
        self._tick_task = asyncio.create_task(self._tick_loop())

    def endpoints(self) -> dict[str, Any]:
        """The state file: each role's endpoint in its driver's address form, and the
        family each twin serves (the station picks the matching driver)."""
        return {
            "speed": self.world.speed,
            "rate_table": endpoint_of(self.table),
            "chamber": endpoint_of(self.chamber),
            "supply": endpoint_of(self.supply),
            # a LAN supply also as its VXI-11 resource (TCPIP::127.0.0.1,<port>::inst0::INSTR)
            **({"supply_vxi11": self.supply.vxi11_endpoint()}
               if hasattr(self.supply, "vxi11_endpoint") else {}),
            "duts": {str(i): f.port.path for i, f in self.fixtures.items()},
            "boards": {str(b.number): sorted(b.twins) for b in self.boards},
            "control": self.control.endpoint,
            "operator": self.eyes.endpoint,
            "inclinometers": {str(s): i.endpoint() for s, i in self.inclinometers.items()},
            "pid": os.getpid(),
            "sockets": len(self.fixtures),
            "families": dict(self.families),
            "lockstep": self.world.lockstep,
        }

    async def _tick_loop(self) -> None:
        if self.world.lockstep:
            return  # the world moves only when the station's clock asks (cmd advance)
        while True:
            t = self.world.advance()
            self._tick_fixtures(t)
            self.ticks += 1
            streaming = any(f.socket.streaming for f in self.fixtures.values())
            await asyncio.sleep(TICK_WALL_S if streaming else IDLE_TICK_WALL_S)

    async def stop(self) -> None:
        if self._tick_task is not None:
            self._tick_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._tick_task
        await self.control.shutdown()
        await self.eyes.shutdown()
        for inclinometer in self.inclinometers.values():
            await inclinometer.shutdown()
        for twin in (self.table, self.chamber, self.supply):
            await twin.shutdown()
        for board in self.boards:
            board.close()

    # ------------------------------------------------------------ control channel

    async def dispatch(self, req: dict[str, Any]) -> Any:
        cmd = req["cmd"]
        if cmd == "ping":
            return {"time_s": self.world.advance(), "speed": self.world.speed}
        if cmd == "advance":
            return self._advance(req)
        if cmd == "truth":
            return self.truth()
        if cmd == "endpoints":
            return self.endpoints()
        if cmd == "load":
            return self._load(req)
        if cmd == "unload":
            self.world.unload_part(self._socket_index(req))
            return {"socket": self._socket_index(req)}
        if cmd == "fault":
            return await self._fault(req)
        if cmd == "clear_faults":
            await self._clear_faults()
            return {"cleared": True}
        raise ControlRequestError(
            f"unknown cmd {cmd!r}; use ping, advance, truth, endpoints, load, unload, fault, "
            "clear_faults"
        )

    def _advance(self, req: dict[str, Any]) -> dict[str, Any]:
        """Lockstep: move the world to `to_s` and send every sample frame due by then. The
        reply's `seq` gives, per socket that sent frames, the last frame's sequence number:
        the station waits for it before it goes on."""
        if not self.world.lockstep:
            raise ControlRequestError(
                "advance needs a lockstep bench (station bench --lockstep); this one runs "
                f"at {self.world.speed:g}x on its own clock"
            )
        to_s = _number(req, "to_s", 0.0, 0.0, 1e9)
        t = self.world.advance_to(to_s)
        sent = {index: f.socket.frames_sent for index, f in self.fixtures.items()}
        self._tick_fixtures(t)
        last_seq: dict[str, int] = {}
        for index, fixture in self.fixtures.items():
            if fixture.socket.frames_sent > sent[index]:
                last_seq[str(index)] = (fixture.socket.seq - 1) % SEQ_MODULO
        return {"time_s": t, "seq": last_seq}

    def _socket_index(self, req: dict[str, Any]) -> int:
        try:
            index = int(req.get("socket", 1))
        except (TypeError, ValueError, OverflowError):
            raise ControlRequestError("socket must be an integer") from None
        if index not in self.world.sockets:
            raise ControlRequestError(
                f"no socket {index}; this bench has sockets 1..{len(self.world.sockets)}"
            )
        return index

    def _load(self, req: dict[str, Any]) -> dict[str, Any]:
        index = self._socket_index(req)
        part = req.get("part") or {}
        if not isinstance(part, dict):
            raise ControlRequestError(
                'part must be an object of part parameters, e.g. {"serial": "SIM-0001"}'
            )
        part = dict(part)
        part["socket"] = index
        try:
            spec = PartSpec.model_validate(part)
        except ValidationError as exc:
            msgs = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
            raise ControlRequestError(f"bad part: {msgs}") from None
        sock = self.world.load_part(spec)
        assert sock.part is not None
        return {"socket": index, "parameters": sock.part.params.as_dict()}

    async def _fault(self, req: dict[str, Any]) -> dict[str, Any]:
        kind = req.get("kind")
        if not isinstance(kind, str) or kind not in FAULT_KINDS:
            raise ControlRequestError(
                f"unknown fault kind {kind!r}; use one of {', '.join(FAULT_KINDS)}"
            )
        w = self.world
        if kind in ("modbus_drop", "modbus_delay"):
            for twin in self._modbus_targets(req.get("target", "all")):
                if kind == "modbus_drop":
                    await twin.drop()
                else:
                    twin.delay_s = _number(req, "delay_s", 5.0, 0.0, 600.0)
        elif kind == "table_fault":
            code = req.get("code", "following_error")
            if not isinstance(code, str) or code not in _TABLE_FAULTS:
                raise ControlRequestError(
                    f"table_fault code {code!r}; use one of {', '.join(_TABLE_FAULTS)}"
                )
            w.trip_table(_TABLE_FAULTS[code])
        elif kind == "interlock_open":
            w.set_interlock(True)
        elif kind == "chamber_stuck":
            w.advance()
            w.chamber.stuck = True
            w.chamber.stuck_reports_fault = bool(req.get("report_fault", False))
        else:
            self._socket_fault(kind, req)
        w.advance()
        return {"kind": kind}

    def _socket_fault(self, kind: str, req: dict[str, Any]) -> None:
        sock = self.world.socket(self._socket_index(req))
        self.world.advance()
        if kind == "supply_short":
            if sock.part is None:
                raise ControlRequestError(
                    f"socket {sock.socket} has no part to short; load one first"
                )
            sock.part.shorted = True
        elif kind == "stream_corrupt":
            sock.corrupt_byte_rate = _rate(req, "byte_error_rate", 1e-3)
        elif kind == "stream_drop":
            sock.drop_frame_rate = _rate(req, "frame_drop_rate", 1e-2)
        elif kind == "part_silent":
            sock.part_silent = True
        elif kind == "fixture_silent":
            sock.fixture_silent = True
        elif kind == "part_absent":
            sock.absent = True

    def _modbus_targets(self, target: str) -> list[Any]:
        options: dict[str, list[Any]] = {
            "table": [self.table],
            "chamber": [self.chamber],
            "all": [self.table, self.chamber],
        }
        if not isinstance(target, str) or target not in options:
            raise ControlRequestError(f"target {target!r}; use table, chamber or all")
        return options[target]

    async def _clear_faults(self) -> None:
        for twin in (self.table, self.chamber):
            twin.delay_s = 0.0
            await twin.restore()
        self.world.clear_world_faults()

    def truth(self) -> dict[str, Any]:
        out = self.world.truth()
        out["modbus"] = {
            name: {
                "dropped": getattr(twin, "dropped", False),
                "delay_s": twin.delay_s,
                "requests": getattr(twin, "requests", 0),
            }
            for name, twin in (("table", self.table), ("chamber", self.chamber))
        }
        for index, fixture in self.fixtures.items():
            out["sockets"][str(index)]["fifo_pending_bytes"] = fixture.port.pending_bytes
            out["sockets"][str(index)]["fifo_peak_bytes"] = fixture.fifo_peak_bytes
            out["sockets"][str(index)]["fifo_bytes"] = fixture.fifo_bytes
        out["ticks"] = self.ticks
        out["operator"] = {"prompts": self.eyes.truth()}
        return out


def _number(req: dict[str, Any], key: str, default: float, low: float, high: float) -> float:
    """The number `req[key]` (default if absent) within [low, high]; ControlRequestError if it
    is not a number or out of range (NaN included)."""
    raw = req.get(key, default)
    try:
        value = float(raw) if not isinstance(raw, bool) else float("nan")
    except (TypeError, ValueError, OverflowError):
        value = float("nan")
    if not low <= value <= high:
        raise ControlRequestError(f"{key} must be between {low:g} and {high:g}")
    return value


def _rate(req: dict[str, Any], key: str, default: float) -> float:
    return _number(req, key, default, 0.0, 1.0)


def write_state(path: Path, state: dict[str, Any]) -> None:
    """Write the state file atomically (readers never see half a file)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(state, indent=2) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def ready_line(state: dict[str, Any], state_path: Path | None) -> str:
    """One line saying the bench is ready: where the state file is and every endpoint."""
    duts = state.get("duts", {})
    dut_text = " ".join(f"{k}={v}" for k, v in duts.items()) or "none"
    where = f"state file {state_path}" if state_path is not None else "state on stdout"
    pace = "in lockstep" if state.get("lockstep") else f"at {state.get('speed')}x"
    return (
        f"bench ready {pace}: {where}; rate_table {state.get('rate_table')}, "
        f"chamber {state.get('chamber')}, supply {state.get('supply')}, duts {dut_text}, "
        f"control {state.get('control')} (Ctrl-C or SIGTERM stops it)"
    )


async def serve(
    config: SimConfig,
    state_path: Path | None,
    speed: float | None = None,
    ports: dict[str, int] | None = None,
    lockstep: bool = False,
) -> None:
    """Run the bench until SIGINT or SIGTERM (in lockstep: its world moves only on `advance`)."""
    ports = ports or {}
    bench = Bench(
        config,
        speed,
        table_port=ports.get("rate_table", 0),
        chamber_port=ports.get("chamber", 0),
        control_port=ports.get("control", 0),
        lockstep=lockstep,
    )
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        await bench.start()
        state = bench.endpoints()
        if state_path is not None:
            write_state(state_path, state)
            print(ready_line(state, state_path), flush=True)
        else:  # stdout carries the state itself for scripts; the human line goes to stderr
            print(json.dumps(state), flush=True)
            print(ready_line(state, None), file=sys.stderr, flush=True)
        log.info("bench running at %gx: %s", bench.world.speed, state)
        started = time.monotonic()
        await stop.wait()
        log.info("bench stopping after %.1f s wall", time.monotonic() - started)
    finally:
        await bench.stop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)


def run_bench(
    config: SimConfig,
    state_path: Path | None,
    speed: float | None = None,
    ports: dict[str, int] | None = None,
    lockstep: bool = False,
) -> int:
    asyncio.run(serve(config, state_path, speed, ports, lockstep))
    sys.stdout.flush()
    return 0
