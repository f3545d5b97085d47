"""Frame parser speed (a measurement, not a test): `python3 benchmarks/bench_parser.py`.

Prints microseconds per frame for 10^6 frames fed in chunks of several sizes.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers import fixture_protocol as fp  # noqa: E402


def main(n: int = 1_000_000) -> None:
    i = np.arange(n, dtype=np.int64)
    t0 = time.perf_counter()
    data = fp.encode_samples(i, i * 1000, fp.RATE_ZERO_CODE + i % 5000,
                             np.full(n, fp.TEMP_ZERO_CODE), np.zeros(n, dtype=np.int64))
    print(f"encode: {(time.perf_counter() - t0) / n * 1e6:.2f} us/frame")
    for frames_per_feed in (10, 50, 195, 1000, 50_000):
        chunk = frames_per_feed * fp.SAMPLE_FRAME_SIZE - 7  # frames split across feeds
        parser = fp.FrameParser()
        t0 = time.perf_counter()
        got = 0
        for k in range(0, len(data), chunk):
            got += parser.feed(data[k : k + chunk]).seq.size
        dt = time.perf_counter() - t0
        assert got == n and parser.frames_lost == 0
        print(f"parse, ~{frames_per_feed} frames per feed: {dt / n * 1e6:.2f} us/frame")


if __name__ == "__main__":
    main()
