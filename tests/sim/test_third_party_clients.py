"""Real third-party clients read the twins: mbpoll (Modbus TCP) and socat (serial)."""

import re
import subprocess

import pytest

from drivers.rate_table_map import COUNTS_PER_REV
from drivers.sim.launcher import BenchEndpoints, BenchHandle


def _mbpoll(bench: BenchHandle, ref: int, count: int, dtype: str) -> dict[int, str]:
    host, port = BenchEndpoints.host_port(bench.endpoints.rate_table)
    out = subprocess.run(
        [
            "mbpoll",
            "-m",
            "tcp",
            "-a",
            "1",
            "-0",
            "-1",
            "-B",
            "-r",
            str(ref),
            "-c",
            str(count),
            "-t",
            dtype,
            "-p",
            str(port),
            host,
        ],
        capture_output=True,
        text=True,
        timeout=20,
    )
    assert out.returncode == 0, out.stderr
    return {int(a): v for a, v in re.findall(r"^\[(\d+)\]:\s+(\S+)", out.stdout, re.MULTILINE)}


@pytest.mark.usefixtures("mbpoll")
def test_mbpoll_reads_model_string_and_encoder(bench: BenchHandle) -> None:
    words = _mbpoll(bench, 40, 8, "4:hex")
    raw = b"".join(int(words[40 + i], 16).to_bytes(2, "big") for i in range(8))
    assert raw.rstrip(b"\0").decode() == "SIM-RT-360"
    values = _mbpoll(bench, 22, 2, "4:int")  # encoder counts (22-23) and position (24-25)
    counts, pos_mdeg = int(values[22]), int(values[24])
    truth = bench.control.truth()["table"]["position_deg"]  # since the last zeroing
    assert abs(counts * 360 / COUNTS_PER_REV - truth) < 1.0  # table may be moving a little
    assert abs(pos_mdeg / 1000 - counts * 360 / COUNTS_PER_REV) < 1.0


@pytest.mark.usefixtures("socat")
def test_socat_gets_the_supply_identity(bench: BenchHandle) -> None:
    out = subprocess.run(
        ["socat", "-t", "1", "-", f"{bench.endpoints.supply},raw,echo=0"],
        input="*IDN?\n",
        capture_output=True,
        text=True,
        timeout=20,
    )
    assert out.returncode == 0, out.stderr
    fields = out.stdout.strip().split(",")
    assert fields[0] == "GYROCAL SIMULATED BENCH" and len(fields) == 4
