"""The station's prompts, written where the simulated operator can read them.

On the simulated bench the operator who turns a fixture by hand is simulated too; like a
real operator it only sees what the station shows. `PromptRelay` subscribes to a run's
progress events and writes each `prompt` / `prompt_done` event as one JSON line to the
bench's `operator` endpoint (its state file; drivers/sim/operator_eyes.py). Best effort: a
relay that cannot write logs it and the run goes on (an unseen prompt ends in the step's
own timeout, as with a real operator who looked away).
"""

from __future__ import annotations

import json
import logging
import socket
import threading
import time

from common.address import split_host_port
from procedures.runtime.progress import ProgressEvent

log = logging.getLogger(__name__)
PROMPT_KINDS = ("prompt", "prompt_done")
CONNECT_TIMEOUT_S = 2.0


class PromptRelay:
    """A progress subscriber forwarding prompts to `endpoint` (host:port)."""

    def __init__(self, endpoint: str) -> None:
        self.address = split_host_port(endpoint)  # ValueError naming the form
        self._sock: socket.socket | None = None
        self._lock = threading.Lock()
        self.sent = 0

    def __call__(self, event: ProgressEvent) -> None:
        if event.kind not in PROMPT_KINDS:
            return
        line = json.dumps(
            {
                "kind": event.kind,
                "message": event.message,
                "sockets": {str(k): v for k, v in event.sockets.items()},
                "step": event.step,
                "condition": event.condition,
                # a reorientation prompt's face ("+x" .. "-z"); absent from other prompts
                **({"orientation": event.orientation} if event.orientation else {}),
                # when it was shown, on the machine's monotonic clock (the bench's clock)
                "monotonic_s": time.monotonic(),
            }
        ).encode() + b"\n"
        with self._lock:
            for _ in range(2):  # a stale connection is reopened once
                try:
                    if self._sock is None:
                        self._sock = socket.create_connection(self.address, CONNECT_TIMEOUT_S)
                    self._sock.sendall(line)
                    self.sent += 1
                    return
                except OSError as exc:
                    self._close()
                    last = exc
            log.warning("the prompt could not be shown to the simulated operator: %s", last)

    def _close(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            finally:
                self._sock = None

    def close(self) -> None:
        with self._lock:
            self._close()
