"""A small typed client for the simulated bench's control channel (tests and benchmarks).

with ControlClient("127.0.0.1:5029") as ctl:
    ctl.load(1, {"serial": "SIM-0001", "bias_dps": 8.6})
    ctl.fault("stream_drop", socket=1, frame_drop_rate=0.01)
    truth = ctl.truth()
"""

from __future__ import annotations

import json
import socket
import threading
from types import TracebackType
from typing import Any

from common.address import split_host_port


class ControlError(RuntimeError):
    """The bench refused a control request (the message says why) or cannot be reached."""


class ControlTimeout(ControlError):
    """The bench did not answer a control request in time (its process stopped or frozen)."""


class ControlClient:
    """One TCP connection to the control channel; thread-safe, one request at a time."""

    def __init__(self, endpoint: str, timeout_s: float = 10.0) -> None:
        self.endpoint = endpoint
        host, port = split_host_port(endpoint)
        try:
            self._sock = socket.create_connection((host, port), timeout=timeout_s)
        except OSError as exc:
            raise ControlError(
                f"cannot reach the bench's control channel at {endpoint} ({exc}); "
                "is the bench running?"
            ) from None
        self._file = self._sock.makefile("rwb")
        self._lock = threading.Lock()

    def request(self, cmd: str, **params: Any) -> Any:
        """Send one request and return its result; raises ControlError when refused."""
        line = json.dumps({"cmd": cmd, **params}).encode() + b"\n"
        with self._lock:
            try:
                self._file.write(line)
                self._file.flush()
                reply_line = self._file.readline()
            except TimeoutError:
                raise ControlTimeout(f"control channel {self.endpoint} did not answer {cmd} "
                                     f"within {self._sock.gettimeout()} s") from None
            except OSError as exc:
                raise ControlError(f"control channel {self.endpoint} failed: {exc}") from None
        if not reply_line:
            raise ControlError(f"control channel {self.endpoint} closed; did the bench stop?")
        reply = json.loads(reply_line)
        if not reply.get("ok"):
            raise ControlError(f"bench refused {cmd}: {reply.get('error')}")
        return reply.get("result")

    # ------------------------------------------------------------ typed helpers

    def ping(self) -> dict[str, float]:
        return self.request("ping")

    def truth(self) -> dict[str, Any]:
        """The world's truth: time, table, chamber, supply, every socket, and a `safe` summary."""
        return self.request("truth")

    def world_time_s(self) -> float:
        return float(self.ping()["time_s"])

    def load(self, socket_index: int, part: dict[str, Any]) -> dict[str, Any]:
        """Put a part in a socket (keys as in the sim config's `parts` entries)."""
        return self.request("load", socket=socket_index, part=part)

    def unload(self, socket_index: int) -> None:
        self.request("unload", socket=socket_index)

    def fault(self, kind: str, **params: Any) -> None:
        """Inject a fault: modbus_drop, modbus_delay, table_fault, interlock_open,
        chamber_stuck, supply_short, stream_corrupt, stream_drop, part_silent,
        fixture_silent, part_absent (see drivers/sim/bench.py for parameters)."""
        self.request("fault", kind=kind, **params)

    def clear_faults(self) -> None:
        self.request("clear_faults")

    def close(self) -> None:
        try:
            self._file.close()
        finally:
            self._sock.close()

    def __enter__(self) -> ControlClient:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
