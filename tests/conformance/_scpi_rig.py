"""The supply families' conformance rigs: a twin served as the bench serves it (the generic
supply on a real pseudo-terminal, the LAN supplies on a raw socket and over VXI-11), reached
through pyvisa with pyvisa-py as a user would; and the checks every IEEE 488.2 instrument
passes, written once for the three families' modules."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import pyvisa

from drivers.sim.bench import twin_class
from drivers.sim.config import SimConfig
from drivers.sim.world import World

ONE_PART: dict[str, Any] = {"parts": [{"socket": 1, "serial": "SIM-K001"}]}
AT_ONCE_S = 0.5  # a reply "at once": well inside any client's timeout, far from a hang


class Served:
    """One twin on its own loop thread, and a pyvisa resource on it."""

    def __init__(self, family: str, transport: str, channel: int = 1) -> None:
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self._thread.start()
        self.world = World(SimConfig.model_validate(ONE_PART), 100.0)
        kind = twin_class("supply", family)
        self.twin = kind(self.world, "127.0.0.1", 0, channel) if family != "scpi" else kind(
            self.world, "127.0.0.1", 0)
        asyncio.run_coroutine_threadsafe(self.twin.start(), self.loop).result(10)
        resource = {"pty": lambda: f"ASRL{self.twin.endpoint()}::INSTR",
                    "socket": self.twin.endpoint,
                    "vxi11": lambda: self.twin.vxi11_endpoint()}[transport]()
        self.rm = pyvisa.ResourceManager("@py")
        self.visa: Any = self.rm.open_resource(
            resource, read_termination="\n", write_termination="\n", timeout=3000)

    def ask(self, message: str) -> str:
        return str(self.visa.query(message))

    def send(self, message: str) -> None:
        self.visa.write(message)

    def errors(self, query: str = "SYST:ERR?") -> list[str]:
        found = []
        for _ in range(40):
            reply = self.ask(query)
            if reply.lstrip("+").startswith("0,"):
                return found
            found.append(reply)
        raise AssertionError(f"the error queue did not empty: {found}")

    def close(self) -> None:
        self.visa.close()
        asyncio.run_coroutine_threadsafe(self.twin.shutdown(), self.loop).result(10)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(5)
        self.loop.close()


@contextmanager
def served(family: str, transport: str, channel: int = 1) -> Iterator[Served]:
    rig = Served(family, transport, channel)
    try:
        yield rig
    finally:
        rig.close()


def answered_at_once(rig: Served, message: str) -> str:
    """The reply to `message`, which must come inside AT_ONCE_S (a client waiting on *OPC?
    gets its answer, never its timeout)."""
    rig.visa.timeout = round(AT_ONCE_S * 1000)
    try:
        start = time.monotonic()
        reply = rig.ask(message)
        assert time.monotonic() - start < AT_ONCE_S
        return reply
    finally:
        rig.visa.timeout = 3000


# ---------------------------------------------------------------- IEEE 488.2, once


def check_status_reporting(rig: Served, nr1: Callable[[int], str], undefined: str) -> None:
    """*ESR? latches the error's class and clears on reading; *ESE enables it into the
    status byte's ESB (32), *SRE into MSS (64); the error queue shows as bit 2; *CLS empties
    queue and registers (IEEE 488.2 11.4-11.5, SCPI-1999 vol. 1 9.1)."""
    rig.send("*CLS")
    assert rig.ask("*ESR?") == nr1(0) and rig.ask("*STB?") == nr1(0)
    rig.send(undefined)  # a command error: -113, ESR bit 5
    assert rig.ask("*STB?") == nr1(4)  # the error queue is not empty
    rig.send("*ESE 32")
    assert rig.ask("*ESE?") == nr1(32)
    assert rig.ask("*STB?") == nr1(4 + 32)
    rig.send("*SRE 36")
    assert rig.ask("*SRE?") == nr1(36)
    assert rig.ask("*STB?") == nr1(4 + 32 + 64)
    assert rig.ask("*ESR?") == nr1(32)
    assert rig.ask("*ESR?") == nr1(0)  # read clears it
    rig.send("*CLS")
    assert rig.ask("*STB?") == nr1(0)  # the queue emptied too
    rig.send("*SRE 0;*ESE 0")
    assert (rig.ask("*SRE?"), rig.ask("*ESE?")) == (nr1(0), nr1(0))


def check_synchronisation(rig: Served, nr1: Callable[[int], str]) -> None:
    """*OPC? answers 1 at once; *OPC sets ESR bit 0 at once; *WAI returns at once."""
    assert answered_at_once(rig, "*OPC?") == "1"
    rig.send("*CLS;*OPC")
    assert answered_at_once(rig, "*ESR?") == nr1(1)
    rig.send("*WAI")
    assert answered_at_once(rig, "*STB?") == nr1(0)


def check_error_queue(rig: Served, query: str, undefined: str, no_error: str) -> None:
    """First in, first out; `<code>,"<text>"`; the queue's 21st error is -350 in its place."""
    rig.send("*CLS")
    assert rig.ask(query) == no_error
    rig.send(undefined)
    rig.send("*ESE 256")  # -222 Data out of range
    assert rig.errors(query) == ['-113,"Undefined header"', '-222,"Data out of range"']
    for _ in range(25):
        rig.send(undefined)
    queued = rig.errors(query)
    assert len(queued) == 20 and queued[-1] == '-350,"Queue overflow"', queued
