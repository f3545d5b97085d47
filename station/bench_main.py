"""`python -m station.bench_main ARGS` is `station bench ARGS` without importing the other
commands (their analysis and report modules): the simulated bench's process starts seconds
sooner. `drivers.sim.launcher` starts the bench this way."""

import sys

from station.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]], modules=("station.cli_bench",)))
