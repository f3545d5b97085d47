"""A fixture board of the simulated bench: a few sockets (eight on the line's boards), each
socket's microcontroller on its own serial port (a pseudo-terminal), as the board's USB hub
presents them. A load of 32 sockets is four boards; each is its own twin, and the state file
names which sockets each board holds (`boards`).
"""

from __future__ import annotations

import asyncio

from drivers.sim.pty_twins import FixtureTwin
from drivers.sim.world import World


class FixtureBoardTwin:
    """The given sockets of the world on one board, a FixtureTwin (its own pty) each."""

    def __init__(
        self,
        world: World,
        number: int,
        sockets: list[int],
        loop: asyncio.AbstractEventLoop,
        fifo_bytes: int,
    ) -> None:
        self.number = number
        self.twins = {s: FixtureTwin(world, world.sockets[s], loop, fifo_bytes) for s in sockets}

    def send(self, frames_by_socket: dict[int, bytes]) -> None:
        """Send each of this board's sockets its sample frames (sockets not here ignored)."""
        for sock, frames in frames_by_socket.items():
            twin = self.twins.get(sock)
            if twin is not None:
                twin.send_samples(frames)

    def ports(self) -> dict[str, str]:
        """Socket number (text, as in the state file) -> its pty path."""
        return {str(s): t.port.path for s, t in self.twins.items()}

    def close(self) -> None:
        for twin in self.twins.values():
            twin.close()


def board_sockets(sockets: list[int], per_board: int) -> list[list[int]]:
    """The world's sockets cut into boards of `per_board` (the last board may hold fewer)."""
    ordered = sorted(sockets)
    return [ordered[i : i + per_board] for i in range(0, len(ordered), per_board)]
