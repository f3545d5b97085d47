"""Whatever the engine puts in record.analysis, a certificate is still issued."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from procedures.runtime.record import RECORD_FILE, RECORD_FORMAT_1, read_record
from reports.certificate import certificate_bytes

_json = st.recursive(
    st.none() | st.booleans() | st.floats(allow_nan=True, allow_infinity=True)
    | st.integers(-10**6, 10**6) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=6), inner,
                                                                  max_size=4),
    max_leaves=12,
)
_numbers = st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), max_size=6)
_analysis = st.fixed_dictionaries({}, optional={
    "allan": st.fixed_dictionaries({}, optional={
        "tau_s": _numbers | _json, "adev_dps": _numbers | _json,
        "arw_deg_per_sqrt_h": _json, "bias_instability_deg_per_h": _json}),
    "rate_table": st.dictionaries(st.sampled_from(["T25_V4.75", "X"]), st.fixed_dictionaries(
        {}, optional={"rate_in_dps": _numbers, "rate_out_dps": _numbers,
                      "residual_dps": _numbers | _json, "scale": _json}) | _json, max_size=2),
    "stop_method": st.dictionaries(st.sampled_from(["T25_V4.75", "T45_V5.25", "Y"]),
                                   st.fixed_dictionaries({}, optional={
                                       "static_windows": _json, "moves": _json,
                                       "bias_dps": _json}) | _json, max_size=2),
    "stability": st.dictionaries(st.sampled_from(["T25_V4.75", "Z"]), _json, max_size=2),
})


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                 HealthCheck.function_scoped_fixture])
@given(analysis=_analysis, verification=_json)
def test_any_analysis_content_still_gives_a_pdf(pass_run: Path, tmp_path: Path,
                                                analysis: dict, verification: object) -> None:
    folder = tmp_path / "run"
    if not folder.exists():
        shutil.copytree(pass_run, folder)
    # A format-2 record refuses such content on validation (procedures/runtime/results.py), so
    # arbitrary analysis can only come from a format-1 record: written as one, it is read
    # through the converter and must still render.
    data = read_record(pass_run).model_dump(mode="json")
    data.update(format=RECORD_FORMAT_1, analysis=analysis,
                verification=verification if isinstance(verification, dict) else None)
    (folder / RECORD_FILE).write_text(json.dumps(data))
    pdf = certificate_bytes(folder)
    assert pdf.startswith(b"%PDF") and b"PASS" in pdf
