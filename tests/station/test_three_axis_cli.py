"""`station run --sim` without a sim config puts parts of the product's kind in the scanned
sockets: a three-axis procedure gets three-axis parts in cubes, a single-axis one single-axis
parts, as before."""

from __future__ import annotations

import argparse
from pathlib import Path

from station.cli.run import _product_axes, _sim_config

ROOT = Path(__file__).resolve().parents[2]


def _args(procedure: str, product: str | None = None) -> argparse.Namespace:
    return argparse.Namespace(station=None, procedure=str(ROOT / procedure), product=product)


def test_the_scanned_parts_follow_the_products_axes() -> None:
    three = _product_axes(_args("config/procedures/eol-three-axis.yaml"))
    single = _product_axes(_args("config/procedures/eol-rate-table.yaml"))
    assert (three, single) == (3, 1)
    duts = {1: "IMU-0001", 3: "IMU-0003"}
    config, _speed = _sim_config(None, duts, three)
    assert config["parts"] == [{"socket": 1, "serial": "IMU-0001", "three_axis": {}},
                               {"socket": 3, "serial": "IMU-0003", "three_axis": {}}]
    config, _speed = _sim_config(None, {1: "SIM-0001"}, single)
    assert config["parts"] == [{"socket": 1, "serial": "SIM-0001"}]


def test_an_unreadable_procedure_leaves_the_choice_to_the_runner(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("steps: [")
    assert _product_axes(_args(str(bad))) == 1  # the runner then refuses it in its own words
