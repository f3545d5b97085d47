"""Helpers of the byte-level driver tests: the Modbus PDUs of the pairs given to
tests/drivers/expected_protocol.py (`TcpPeer(pairs, MODBUS)`), and `ManualClock`, a station
clock that advances only when slept on, so timeouts are tested instantly and exactly.
"""

from __future__ import annotations

import struct


def read_pdu(address: int, count: int) -> bytes:
    return struct.pack(">BHH", 3, address, count)


def read_reply(regs: list[int]) -> bytes:
    return struct.pack(f">BB{len(regs)}H", 3, 2 * len(regs), *[r & 0xFFFF for r in regs])


def write_pdu(address: int, value: int) -> bytes:
    return struct.pack(">BHH", 6, address, value & 0xFFFF)


def write_many_pdu(address: int, regs: list[int]) -> bytes:
    return struct.pack(
        f">BHHB{len(regs)}H", 16, address, len(regs), 2 * len(regs), *[r & 0xFFFF for r in regs]
    )


def write_many_reply(address: int, count: int) -> bytes:
    return struct.pack(">BHH", 16, address, count)


def exception_reply(function: int, code: int) -> bytes:
    return bytes([function | 0x80, code])


def str_regs(text: str, count: int) -> list[int]:
    raw = text.encode().ljust(2 * count, b"\0")
    return [int.from_bytes(raw[i : i + 2], "big") for i in range(0, 2 * count, 2)]


def pair(value: int) -> list[int]:
    value &= 0xFFFFFFFF
    return [value >> 16, value & 0xFFFF]


class ManualClock:
    """Station clock that moves only when someone sleeps on it (speed irrelevant)."""

    def __init__(self, speed: float = 1.0) -> None:
        self._now = 0.0
        self._speed = speed
        self.slept_s = 0.0

    @property
    def speed(self) -> float:
        return self._speed

    def now_s(self) -> float:
        return self._now

    def sleep_s(self, duration_s: float) -> None:
        if duration_s > 0:
            self._now += duration_s
            self.slept_s += duration_s

    def wall_timeout_s(self, duration_s: float) -> float:
        return duration_s / self._speed
