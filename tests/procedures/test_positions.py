"""The optional multi-position static step against the simulated bench: one static window
per configured angle in raw.h5 (kind position_static, rate 0, the encoder angle), and a
procedure without the step plans exactly the steps it did before."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from common.yaml_input import ConfigError
from procedures.loading.config import load_procedure
from procedures.loading.plan import build_plan
from procedures.runtime.rawdata import read_raw
from procedures.runtime.record import RAW_DATA_FILE, Verdict, read_record

from .conftest import SHORT, run_on_bench

ANGLES = [0.0, 90.0, 180.0, 270.0]


def _procedure(tmp_path: Path, positions: dict | None) -> Path:
    """SHORT with a positions step after the bias step of the condition loop."""
    data = yaml.safe_load(SHORT.read_text())
    data["product"] = str((SHORT.parent / data["product"]).resolve())
    if positions is not None:
        loop = next(e for e in data["steps"] if e.get("for_each") == "condition")
        at = [e.get("step") for e in loop["steps"]].index("bias") + 1
        loop["steps"].insert(at, {"step": "positions", **positions})
    path = tmp_path / "positions.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_positions_step_writes_a_static_window_per_angle(tmp_path: Path) -> None:
    proc = _procedure(tmp_path, {"angles_deg": ANGLES, "dwell_s": 4, "at": "first_condition"})
    run = run_on_bench(
        tmp_path / "runs", [{"socket": 1, "serial": "SIM-0801"}], speed=200, procedure=proc
    )
    folder = run.result.folders[1]
    rec = read_record(folder)
    assert rec.verdict in (Verdict.PASS, Verdict.FAIL), rec.reason
    seg = read_raw(folder / RAW_DATA_FILE)["segments"]
    kinds = np.asarray([str(k) for k in seg["kind"]])
    pos = kinds == "position_static"
    assert pos.sum() == len(ANGLES)  # first condition only
    angles = np.asarray(seg["ref_angle_deg"])[pos]
    order = np.argsort(np.asarray(seg["index"])[pos])
    assert np.allclose(angles[order], ANGLES, atol=0.01), angles[order]
    assert np.all(np.asarray(seg["ref_rate_dps"])[pos] == 0.0)
    starts, ends = np.asarray(seg["start_s"])[pos], np.asarray(seg["end_s"])[pos]
    assert np.all(ends - starts > 3.5)  # about the 4 s dwell each
    conds = {str(c) for c in np.asarray(seg["condition"])[pos]}
    assert len(conds) == 1
    summary = rec.analysis.positions[conds.pop()]
    assert [round(w.angle_cmd_deg or 0) for w in summary] == [0, 90, 180, 270]


def test_positions_every_condition_and_disabled_plans(tmp_path: Path) -> None:
    base, _ = load_procedure(_procedure(tmp_path, None))
    assert base.settings_of("positions") is None
    names = [s.name for s in build_plan(base)]
    assert "positions" not in names
    every, _ = load_procedure(_procedure(tmp_path, {}))
    assert every.settings_of("positions").angles_deg == ANGLES
    plan = build_plan(every)
    assert [s.name for s in plan if s.name != "positions"] == names
    pos = [i for i, s in enumerate(plan) if s.name == "positions"]
    assert len(pos) == 4 and all(plan[i - 1].name == "bias" for i in pos)
    assert [plan[i].condition for i in pos] == [plan[i - 1].condition for i in pos]
    first, _ = load_procedure(_procedure(tmp_path, {"at": "first_condition"}))
    plan = build_plan(first)
    assert [(s.name, s.place.condition_index) for s in plan if s.name == "positions"] == [
        ("positions", 0)
    ]


def test_positions_config_errors(tmp_path: Path) -> None:
    where = r"steps\.1\.steps\.2\."
    with pytest.raises(ConfigError, match=where + r"dwell_s \(step positions\)"):
        load_procedure(_procedure(tmp_path, {"dwell_s": 0}))
    with pytest.raises(ConfigError, match=where + r"at \(step positions\)"):
        load_procedure(_procedure(tmp_path, {"at": "sometimes"}))
    with pytest.raises(ConfigError, match=where + r"angles_deg \(step positions\)"):
        load_procedure(_procedure(tmp_path, {"angles_deg": []}))
