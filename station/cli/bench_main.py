"""`python -m station.cli.bench_main ARGS` is `station bench ARGS` without importing the other
commands (their analysis and report modules): the simulated bench's process starts seconds
sooner. `drivers.sim.launcher` starts the bench this way.

`GYROCAL_BENCH_PROFILE=PATH` in the environment runs the bench under cProfile and writes its
statistics to PATH when the bench stops (benchmarks/bench_wall.py --profile uses it)."""

import os
import sys

from station.cli.main import main


def _run() -> int:
    args = ["bench", *sys.argv[1:]]
    profile_path = os.environ.get("GYROCAL_BENCH_PROFILE")
    if not profile_path:
        return main(args, modules=("station.cli.bench",))
    import cProfile  # only when profiling (GYROCAL_BENCH_PROFILE)

    profiler = cProfile.Profile()
    try:
        return int(profiler.runcall(main, args, modules=("station.cli.bench",)) or 0)
    finally:
        profiler.dump_stats(profile_path)


if __name__ == "__main__":
    sys.exit(_run())
