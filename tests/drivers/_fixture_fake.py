"""A scripted fixture microcontroller on the master side of a pty, for part-link tests.

It answers the command set of drivers.fixture_protocol and, once started, streams sample
frames at `rate_fps` frames per wall second in 5 ms batches. Hooks let a test damage the
stream (`mangle`), stop the frames (`go_silent`), or make the fixture deaf (`deaf`).
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
import tty
from collections.abc import Callable

import numpy as np

from drivers import fixture_protocol as fp
from tests.drivers.expected_protocol import lines_from, write_all


class FakeFixture:
    def __init__(self, *, rate_fps: float = 2000.0, serial: str = "SIM-0001") -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.rate_fps = rate_fps
        self.serial = serial
        self.commands: list[bytes] = []
        self.cal = "bias=0 scale=1 bias_tc=0 scale_tc=0 bias_vc=0 scale_vc=0 t0=25 v0=5"
        self.part_present = True
        self.deaf = False
        self.go_silent = False
        self.cal_sticky_bias: float | None = None  # a part that does not keep bias
        self.cal_keys: set[str] | None = None  # registers the part holds (None: any written)
        self.knows_stream_query = False  # STREAM? (older firmware answers ERR 2)
        self.stop_ignored = False  # a fixture whose STOP says OK and streams on
        self.mangle: Callable[[bytes, int], bytes] | None = None  # (frames, first_seq) -> bytes
        self.sent = 0
        self.wall_streaming_s = 0.0  # START to STOP, wall seconds
        self._t_start = 0.0
        self.write_blocked_s = 0.0  # wall time spent waiting for the reader to drain the pty
        self._streaming = threading.Event()
        self._stop = threading.Event()
        self._wlock = threading.Lock()
        self._threads = [
            threading.Thread(target=self._commands, daemon=True),
            threading.Thread(target=self._stream, daemon=True),
        ]
        for t in self._threads:
            t.start()

    def _write(self, data: bytes) -> None:
        with self._wlock:
            write_all(self.master, data)

    def reply(self, text: str) -> None:
        self._write(fp.encode_reply(text))

    def _commands(self) -> None:
        for line in lines_from(self.master, self._stop):
            self.commands.append(line)
            if not self.deaf:
                self._handle(line.decode())

    def _handle(self, line: str) -> None:
        word, _, arg = line.partition(" ")
        if word == "IDN?":
            self.reply("OK TestCo,FIX-8,F001,0.9")
        elif word == "PRESENT?":
            self.reply(f"OK {int(self.part_present)}")
        elif word == "SN?":
            self.reply(f"OK {self.serial}" if self.part_present else "ERR 10 no part")
        elif word == "ODR":
            ok = arg.isdigit() and int(arg) in fp.OUTPUT_RATES_HZ
            self.reply("OK" if ok else "ERR 3 rate not supported")
        elif word == "START":
            self.reply("OK")
            self._t_start = time.monotonic()
            self._streaming.set()
        elif word == "STREAM?" and self.knows_stream_query:
            self.reply(f"OK {int(self._streaming.is_set())}")
        elif word == "STOP" and self.stop_ignored:
            self.reply("OK")
        elif word == "STOP":
            self._streaming.clear()
            with self._wlock:  # wait for the batch in flight to be written
                pass
            self.wall_streaming_s += time.monotonic() - self._t_start
            self.reply("OK")
        elif word == "CAL?":
            self.reply(f"OK {self.cal}")
        elif word == "CAL":
            values = dict(item.split("=") for item in arg.split())
            unknown = sorted(set(values) - self.cal_keys) if self.cal_keys is not None else []
            if unknown:
                self.reply(f"ERR 4 no register {unknown[0]!r}")
                return
            if self.cal_sticky_bias is not None:
                values["bias"] = str(self.cal_sticky_bias)
            held = dict(item.split("=") for item in self.cal.split())
            self.cal = " ".join(f"{k}={v}" for k, v in {**held, **values}.items())
            self.reply("OK")
        elif word == "COMP":
            self.reply("OK")
        elif word == "STOPANGLE?":
            self.reply("OK 90.130 0.050")
        else:
            self.reply("ERR 2 unknown command")

    def _stream(self) -> None:
        batch_s = 0.005
        seq = 0
        while not self._stop.is_set():
            if not self._streaming.wait(0.05):
                continue
            t_start = time.monotonic()
            sent_at_start = seq
            while self._streaming.is_set() and not self._stop.is_set():
                due = int((time.monotonic() - t_start) * self.rate_fps) + sent_at_start - seq
                if due <= 0:
                    time.sleep(batch_s)
                    continue
                if self.go_silent:
                    time.sleep(batch_s)
                    continue
                idx = np.arange(seq, seq + due, dtype=np.int64)
                data = fp.encode_samples(
                    idx, idx * 1000, fp.RATE_ZERO_CODE + (idx % 1000),
                    np.full(due, fp.TEMP_ZERO_CODE),
                    np.zeros(due, dtype=np.int64),
                )
                if self.mangle is not None:
                    data = self.mangle(data, seq)
                with self._wlock:
                    if not self._streaming.is_set():
                        break
                    view = memoryview(data)
                    t_write = time.monotonic()
                    while view:
                        view = view[os.write(self.master, view):]
                    self.write_blocked_s += time.monotonic() - t_write
                seq += due
                self.sent = seq

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        self._streaming.clear()
        with contextlib.suppress(OSError):
            os.close(self.master)
        for t in self._threads:
            t.join(1.0)
        os.close(self.slave)


def serve_main(rates: list[float]) -> None:
    """Run fixtures in this process (a separate one from the links, as the bench is): print
    their pty paths as one JSON line, then at each stdin line print each fixture's `sent` and
    streaming wall time; exit when stdin closes."""
    import json
    import sys

    fixtures = [FakeFixture(rate_fps=r) for r in rates]
    print(json.dumps([f.path for f in fixtures]), flush=True)
    for _ in sys.stdin:
        stats = [[f.sent, f.wall_streaming_s, f.write_blocked_s] for f in fixtures]
        print(json.dumps(stats), flush=True)
    for f in fixtures:
        f.close()


if __name__ == "__main__":
    import sys

    serve_main([float(x) for x in sys.argv[1:]])
