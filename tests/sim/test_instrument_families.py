"""The bench's `instruments:` key: which family each twin serves, said in the state file."""

from __future__ import annotations

import pytest

from drivers.sim.bench import TWINS, twin_class
from drivers.sim.config import DEFAULT_FAMILIES, SimConfigError, parse_sim_config
from drivers.sim.launcher import launch_bench


def test_todays_families_are_the_default() -> None:
    assert parse_sim_config({}).instruments.families() == DEFAULT_FAMILIES
    chosen = parse_sim_config(
        {"instruments": {"rate_table": "acutrol", "chamber": "espec-p300",
                         "supply": "rigol-dp800"}}
    ).instruments.families()  # fmt: skip
    assert chosen == {"rate_table": "acutrol", "chamber": "espec-p300",
                      "supply": "rigol-dp800", "part": "fixture"}


@pytest.mark.parametrize(
    "instruments, words",
    [
        ({"chamber": "watlow-f5"}, "instruments.chamber: Input should be 'watlow-f4', "
         "'watlow-f4t' or 'espec-p300'"),
        ({"supply": "scpi", "oven": "x"}, "instruments.oven: Extra inputs are not permitted"),
    ],
)
def test_unknown_families_are_refused_with_the_names_allowed(
    instruments: dict[str, str], words: str
) -> None:
    with pytest.raises(SimConfigError, match=words):
        parse_sim_config({"instruments": instruments})


def test_each_family_has_its_twin_class_or_a_clear_error() -> None:
    assert ("rate_table", "modbus-servo") in TWINS and ("chamber", "watlow-f4") in TWINS
    with pytest.raises(ValueError, match=r"no chamber twin for 'no-such' \(it serves: watlow-f4"):
        twin_class("chamber", "no-such")


def test_the_state_file_says_which_family_each_twin_serves() -> None:
    served = {k: v for k, v in DEFAULT_FAMILIES.items() if k != "part"}
    with launch_bench(config={"instruments": served}, speed=100) as bench:
        state = bench.endpoints.raw
        assert state["families"] == DEFAULT_FAMILIES
        assert bench.endpoints.families == DEFAULT_FAMILIES
    with launch_bench(speed=100) as bench:  # no instruments: key, today's families
        state = bench.endpoints.raw
        assert state["families"] == DEFAULT_FAMILIES
        # every endpoint in its driver's own form: host:port for the Modbus twins
        for role in ("rate_table", "chamber"):
            host, _, port = state[role].rpartition(":")
            assert host == "127.0.0.1" and port.isdigit()
        assert state["supply"].startswith("/dev/pts/")
