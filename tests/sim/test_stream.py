"""A long sample stream through a real pty: no frame lost, timestamps on the fixture's clock."""

import numpy as np

from drivers.fixture_protocol import FrameParser, rate_code_to_dps
from drivers.sim.launcher import launch_bench
from drivers.sim.stream_probe import StreamProbe, power_parts

N_FRAMES = 1_000_000


class _Checker(FrameParser):
    """FrameParser that also checks every sample's timestamp step and the mean rate."""

    def __init__(self) -> None:
        super().__init__()
        self.bad_steps = 0
        self.last_t: float | None = None
        self.sum_dps = 0.0
        self.n = 0

    def feed(self, data):  # type: ignore[no-untyped-def]
        res = super().feed(data)
        if len(res.seq):
            t = res.time_s if self.last_t is None else np.concatenate(([self.last_t], res.time_s))
            self.bad_steps += int(np.sum(np.abs(np.diff(t) - 0.001) > 1e-6))
            self.last_t = float(res.time_s[-1])
            self.sum_dps += float(np.sum(rate_code_to_dps(res.rate_code)))
            self.n += len(res.seq)
        return res


def test_a_million_frames_none_lost() -> None:
    config = {
        "parts": [{"socket": 1, "serial": "SIM-STREAM", "bias_dps": 3.0}],
        # a deep FIFO so a starved shared machine delays frames instead of dropping them:
        # this test checks that the chain loses nothing; bench_stream.py measures throughput
        "fixture": {"fifo_bytes": 32 << 20},
    }
    with launch_bench(config=config, speed=200) as bench:
        power_parts(bench.endpoints.supply)
        with StreamProbe([bench.endpoints.duts[1]]) as probe:
            checker = _Checker()
            probe.parsers[0] = checker
            probe.stream(1000, frames=N_FRAMES)
            truth = bench.control.truth()["sockets"]["1"]
        c = probe.counts[0]
    assert c.frames_ok >= N_FRAMES
    assert c.frames_lost == 0 and c.frames_corrupted == 0 and c.bytes_discarded == 0
    assert truth["frames_dropped"] == 0
    assert c.frames_ok == truth["frames_sent"]  # everything sent arrived, up to STOP
    assert checker.bad_steps == 0  # 1 ms apart on the fixture's clock, every one
    # the table is at rest: the mean output is the part's bias plus its temperature and
    # supply terms (die self-heated a few C above 25 C), and nowhere near zero
    mean = checker.sum_dps / checker.n
    assert 2.5 < mean < 3.5
