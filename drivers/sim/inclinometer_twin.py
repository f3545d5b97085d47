"""The twin of one socket's inclinometer (`inclinometer.ascii-xy`, drivers/inclinometer.py):
`R` -> `X=+xx.xxx` and `Y=+xx.xxx` lines, `V` -> type and serial lines.

X is the fixture's angle (the hand's turn; the table's too, if the bench has one) plus the
sensor's mounting offset (constant, so it cancels in the travel between two stops) and its
reading noise, to three decimals; Y is a small constant tilt with the same noise.
"""

from __future__ import annotations

import numpy as np

from drivers.sim.line_twin import LineTwin
from drivers.sim.world import World

NOISE_DEG = 0.002  # one reading's noise, 1 sigma (the driver averages several)


class InclinometerTwin(LineTwin):
    name = "inclinometer twin"
    overlong_closes = False

    def __init__(self, world: World, socket: int, host: str = "127.0.0.1", port: int = 0) -> None:
        super().__init__(world, host, port)
        self.socket = socket
        rng = np.random.default_rng([world.config.seed, socket, 1717])
        self.offset_deg = float(rng.uniform(-0.5, 0.5))
        self.tilt_deg = float(rng.uniform(-0.2, 0.2))
        self.rng = rng

    def reply(self, line: str) -> str | None:
        command = line.strip().upper()
        if command == "R":
            t = self.world.advance()
            angle = float(self.world.sockets[self.socket].angle_deg(t)[0])
            x = angle + self.offset_deg + self.rng.normal(0.0, NOISE_DEG)
            y = self.tilt_deg + self.rng.normal(0.0, NOISE_DEG)
            return f"X={x:+07.3f}\r\nY={y:+07.3f}"
        if command == "V":
            return f"AGS360-2-S1\r\nSN:SIM-IN{self.socket:03d}"
        return "E"
