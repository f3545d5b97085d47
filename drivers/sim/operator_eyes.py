"""The simulated operator's eyes: the station's prompts, as the operator would read them.

A real operator reads the station's screen; the simulated one reads the same prompts from a
small local socket (the state file's `operator` endpoint, JSON lines), where a station run
against the bench writes every `prompt` / `prompt_done` progress event it shows
(station/prompt_relay.py). Nothing else reaches the hand: not the station's state, not its
instruments, only what the screen says. One line per event:

    {"kind": "prompt", "message": "Turn socket 1's fixture by hand to the other stop",
     "sockets": {"1": "PROMPT"}}

On a prompt the operator turns the fixtures of the sockets named, one after another (one
pair of hands); `prompt_done` needs no action. A prompt that carries `orientation` (a face,
"+x" .. "-z") asks for the three-axis parts' cubes to be turned so that face points up
(drivers/sim/cube.py): the operator turns each named socket's cube instead. Nothing is
answered. A line may carry `monotonic_s`, the machine's monotonic clock when the station
showed the prompt: the operator's reaction counts from then (a busy bench process reads the
line late; a real operator would not see the screen late), but a move never starts before
the world's present, whose samples are already sent.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from typing import Any

from drivers.orientation import normalise_face
from drivers.sim.world import World

log = logging.getLogger(__name__)
MAX_LINE_BYTES = 64 * 1024
KEEP_PROMPTS = 50
MAX_SCREEN_LAG_S = 600.0  # world seconds; older stamps are not trusted


class OperatorEyes:
    """The operator endpoint of the bench: reads prompt lines, moves the hands."""

    def __init__(self, world: World, host: str = "127.0.0.1", port: int = 0) -> None:
        self.world = world
        self.host = host
        self.port = port
        self.seen: list[dict[str, Any]] = []
        self._server: asyncio.Server | None = None
        self._writers: set[asyncio.StreamWriter] = set()

    async def start(self) -> None:
        self._server = await asyncio.start_server(
            self._serve, self.host, self.port, limit=MAX_LINE_BYTES
        )
        self.port = self._server.sockets[0].getsockname()[1]

    @property
    def endpoint(self) -> str:
        return f"{self.host}:{self.port}"

    async def shutdown(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.close()
        for writer in list(self._writers):
            writer.close()
        self._writers.clear()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._writers.add(writer)
        try:
            while True:
                try:
                    raw = await reader.readline()
                except (ValueError, ConnectionError):
                    return
                if not raw:
                    return
                self.read(raw)
        finally:
            self._writers.discard(writer)
            with contextlib.suppress(Exception):
                writer.close()

    def read(self, raw: bytes) -> None:
        """One line of the screen: act on a prompt, ignore anything unreadable."""
        try:
            event = json.loads(raw)
        except (ValueError, UnicodeDecodeError):
            log.info("operator: an unreadable prompt line was ignored")
            return
        if not isinstance(event, dict) or event.get("kind") not in ("prompt", "prompt_done"):
            return
        sockets = _sockets(event.get("sockets"))
        now = self.world.advance()
        t = self._shown_at(event.get("monotonic_s"), now)
        self.seen.append(
            {"time_s": now, "shown_s": t, "kind": event["kind"],
             "message": str(event.get("message", ""))[:200], "sockets": sockets}
        )
        del self.seen[:-KEEP_PROMPTS]
        if event["kind"] != "prompt":
            return
        face = _face(event.get("orientation"))
        if face is not None:
            self._turn_cubes(sockets, face, t, now)
            return
        for index in sockets:  # one pair of hands: one fixture after another
            sock = self.world.sockets.get(index)
            if sock is None:
                continue
            move = sock.hand.on_prompt(t, earliest_s=now)
            if move is not None:
                t = max(t, move.end_s)

    def _turn_cubes(self, sockets: list[int], face: str, t: float, now: float) -> None:
        """Turn each named socket's cube so `face` points up, one after another."""
        for index in sockets:
            sock = self.world.sockets.get(index)
            if sock is None:
                continue
            turn = sock.cube.on_prompt(t, face, earliest_s=now)
            if turn is not None:
                t = max(t, turn.end_s)

    def _shown_at(self, monotonic_s: Any, now: float) -> float:
        """World time the prompt appeared on the screen: the station stamps it with the
        machine's monotonic clock (the world's clock too), so an operator reacts from when
        it was shown even when this process reads it late; `now` if absent or implausible."""
        if isinstance(monotonic_s, bool) or not isinstance(monotonic_s, int | float):
            return now
        shown = self.world.world_time_at(float(monotonic_s))
        return shown if now - MAX_SCREEN_LAG_S <= shown <= now else now

    def truth(self) -> list[dict[str, Any]]:
        return list(self.seen)


def _face(value: Any) -> str | None:
    """The prompt's orientation as a face name, None when absent or not a face."""
    if not isinstance(value, str):
        return None
    try:
        return normalise_face(value)
    except ValueError:
        log.info("operator: a prompt named an unknown orientation %r", value[:20])
        return None


def _sockets(value: Any) -> list[int]:
    """Socket numbers from the event's `sockets` (a mapping or a list), in order."""
    items = value.keys() if isinstance(value, dict) else value if isinstance(value, list) else []
    out: list[int] = []
    for item in items:
        try:
            n = int(item)
        except (TypeError, ValueError):
            continue
        if n not in out:
            out.append(n)
    return sorted(out)
