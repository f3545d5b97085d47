"""The launcher others use to run the bench: endpoints, errors, clean stop."""

import os

import pytest

from drivers.sim.launcher import BenchStartError, launch_bench


def test_launcher_reports_a_bad_config_with_the_bench_message() -> None:
    with pytest.raises(BenchStartError) as err, launch_bench(config={"parts": [{"socket": 0}]}):
        pass
    assert "exited with code 2" in str(err.value)
    assert "parts.0.socket" in str(err.value)


def test_launcher_gives_endpoints_and_stops_the_process() -> None:
    with launch_bench(config={"fixture": {"sockets": 2}}, speed=40) as bench:
        assert bench.speed == 40.0
        assert sorted(bench.endpoints.duts) == [1, 2]
        assert bench.control.truth()["sockets"]["1"]["present"] is False
        pid = bench.process.pid
        os.kill(pid, 0)  # alive
    assert bench.process.returncode == 0
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)
