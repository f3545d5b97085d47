"""The live chart's axis labels (station/ui/static/chart.js `fmt`), run in node: a small
negative value reads as itself, never "-0.00" (issue 26, finding 14)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

CHART_JS = Path(__file__).resolve().parents[2] / "station" / "ui" / "static" / "chart.js"


def labels(values: list[float]) -> list[str]:
    node = shutil.which("node")
    if node is None:
        pytest.skip("node not installed (runs the chart's own label function)")
    source = CHART_JS.read_text(encoding="utf-8")
    match = re.search(r"^function fmt\(v\) \{.*?^\}$|^function fmt\(v\) \{.*?\}$", source,
                      re.S | re.M)
    assert match, "chart.js has no fmt(v)"
    script = f"{match.group(0)}\nconsole.log(JSON.stringify({json.dumps(values)}.map(fmt)));"
    out = subprocess.run([node, "-e", script], capture_output=True, text=True, check=True)
    return list(json.loads(out.stdout))


def test_axis_labels_never_read_minus_zero() -> None:
    got = labels([-0.001, -0.004, 0.003, -1e-15, 0.0, -0.0, 0.5, -12.34, 2500.0])
    assert got == ["-0.0010", "-0.0040", "0.0030", "0", "0", "0", "0.50", "-12.3", "2500"]
    assert not any(re.fullmatch(r"-0(\.0*)?", g) for g in got)
