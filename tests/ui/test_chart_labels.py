"""The live chart's axis labels (station/ui/static/chart.js `fmt`), run in chromium's own
JavaScript engine: a small negative value reads as itself, never "-0.00" (issue 26, finding
14)."""

from __future__ import annotations

import re
from pathlib import Path

from playwright.sync_api import Page

CHART_JS = Path(__file__).resolve().parents[2] / "station" / "ui" / "static" / "chart.js"


def labels(page: Page, values: list[float]) -> list[str]:
    source = CHART_JS.read_text(encoding="utf-8")
    match = re.search(r"^function fmt\(v\) \{.*?^\}$|^function fmt\(v\) \{.*?\}$", source,
                      re.S | re.M)
    assert match, "chart.js has no fmt(v)"
    return list(page.evaluate(f"(values) => {{ {match.group(0)}\n return values.map(fmt); }}",
                              values))


def test_axis_labels_never_read_minus_zero(page: Page) -> None:
    got = labels(page, [-0.001, -0.004, 0.003, -1e-15, 0.0, -0.0, 0.5, -12.34, 2500.0])
    assert got == ["-0.0010", "-0.0040", "0.0030", "0", "0", "0", "0.50", "-12.3", "2500"]
    assert not any(re.fullmatch(r"-0(\.0*)?", g) for g in got)
