"""Data loading (CSV, run folder) and the `station discrepancy` command."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from fake_run_folder import STATION_OFFSET_S, write_run_folder
from helpers_model import TINY, as_trajectory
from synth_gyro import SHORT, Part, generate, realistic_part

from procedures.model.data import load_csv, write_csv
from procedures.model.discrepancy import run_discrepancy
from procedures.model.gyro_model import first_order_model
from procedures.model.run_folder import load_data

ROOT = Path(__file__).resolve().parents[2]
PINNED = {"gap_initial_dps", "noise_floor_dps", "iterations", "effects_added", "gap_final_dps"}


def _station(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "station", "discrepancy", *args],
                          capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)


def test_csv_round_trip_and_inferred_windows(tmp_path: Path) -> None:
    traj = as_trajectory(generate(Part(), 3, TINY))
    back = load_csv(write_csv(tmp_path / "a.csv", traj, with_kinds=True))
    assert np.allclose(back.gyro_dps, traj.gyro_dps, rtol=1e-8)
    assert [s.kind for s in back.segments] == [s.kind for s in traj.segments if
                                               s.end_s - s.start_s > 0.05][: len(back.segments)]
    inferred = load_csv(write_csv(tmp_path / "b.csv", traj, with_kinds=False))
    kinds = {s.kind for s in inferred.segments}
    assert {"static", "plateau", "transition", "stop_move"} <= kinds
    plateau_rates = {round(float(np.median(traj.ref_rate_dps[(traj.time_s >= s.start_s)
                                                              & (traj.time_s < s.end_s)])))
                     for s in inferred.segments if s.kind == "plateau"}
    assert plateau_rates == {20, -20, 200, -200}


def test_bad_csv_is_refused_with_a_clear_message(tmp_path: Path) -> None:
    p = tmp_path / "bad.csv"
    p.write_text("time_s,gyro_dps,ref_rate_dps\n0,1,2\n")
    with pytest.raises(ValueError, match="columns .*ref_angle_deg.* are missing"):
        load_csv(p)
    out = _station(str(p))
    assert out.returncode == 2
    assert "missing" in out.stderr and "Traceback" not in out.stderr


def test_cli_on_csv_writes_pinned_json_model_and_pdf(tmp_path: Path) -> None:
    traj = as_trajectory(generate(realistic_part().with_effect("k3_cubic"), 21, SHORT))
    csv_path = write_csv(tmp_path / "run.csv", traj, with_kinds=False)
    out = _station(str(csv_path), "--model", "first_order", "--out", str(tmp_path / "o"),
                   "--json", str(tmp_path / "r.json"))
    assert out.returncode == 0, out.stderr
    data = json.loads((tmp_path / "r.json").read_text())
    assert set(data) >= PINNED
    assert data["effects_added"][0] == "k3_cubic"
    it = data["iterations"][0]
    assert {"effect", "gap_before_dps", "gap_after_dps", "parameters", "evidence"} <= set(it)
    assert it["parameters"]["k3_per_dps2"] == pytest.approx(8e-9, rel=0.2)
    assert data["gap_final_dps"] <= 1.5 * data["noise_floor_dps"] < data["gap_initial_dps"]
    pdf = (tmp_path / "o" / "discrepancy_report.pdf").read_bytes()
    assert pdf.startswith(b"%PDF") and b"/Subtype /Image" not in pdf  # vector only
    assert pdf.count(b"/Type /Page\n") >= 2
    # the extended model is a valid starting model: nothing more to name
    again = _station(str(csv_path), "--model", str(tmp_path / "o" / "model.yaml"),
                     "--out", str(tmp_path / "o2"))
    assert again.returncode == 0, again.stderr
    d2 = json.loads((tmp_path / "o2" / "discrepancy.json").read_text())
    assert d2["effects_added"] == []
    assert d2["gap_initial_dps"] <= 1.5 * d2["noise_floor_dps"]


@pytest.mark.parametrize(("table_shift_deg", "index_offset_deg"), [(37.0, 123.4), (0.0, 0.0)])
def test_run_folder_with_latched_encoder_uses_every_sample_with_its_own_reference(
    tmp_path: Path, table_shift_deg: float, index_offset_deg: float
) -> None:
    """Hardware sync: the reference of each sample is the table's mean rate since the
    previous sample (two latched counts) and its angle at the sample, transitions included;
    the angle is brought into the table's frame (here 37 deg from where the record starts);
    a sample after a lost frame is left out. Index offset 0: the u32 counter wraps below 0."""
    run = generate(Part(), 5, TINY)
    run["ref_angle_deg"] = (np.asarray(run["ref_angle_deg"]) + table_shift_deg) % 360.0
    keep = np.ones(np.asarray(run["time_s"]).size, dtype=bool)
    keep[1500] = False  # one lost frame
    cut = {k: (np.asarray(v)[keep] if k != "segments" else v) for k, v in run.items()}
    cpr = 1 << 20
    folder = write_run_folder(tmp_path / "run", cut, latched_counts_per_rev=cpr,
                              encoder_index_offset_deg=index_offset_deg)
    if index_offset_deg == 0.0:
        with h5py.File(folder / "raw.h5", "r") as f:
            assert f["samples/encoder_counts"][()].max() > (1 << 32) - cpr  # it did wrap
    traj = load_data(folder)
    assert any("hardware sync" in n for n in traj.notes)
    t = np.asarray(cut["time_s"])
    angle = np.unwrap(np.asarray(cut["ref_angle_deg"]), period=360.0)
    used = np.isin(t, traj.time_s)
    assert not used[0] and not used[1500]  # no previous latch for these two
    assert used.sum() == t.size - 2  # everything else, transitions too
    mean_rate = np.diff(angle) / np.diff(t)
    expect = np.concatenate([[np.nan], mean_rate])[used]
    assert np.max(np.abs(traj.ref_rate_dps - expect)) <= 2 * (360.0 / cpr) / np.min(np.diff(t))
    moving = np.abs(np.gradient(np.asarray(cut["ref_rate_dps"]), t)) > 50.0
    assert (moving & used).sum() > 50  # accelerations carry a reference now
    off = (traj.ref_angle_deg - angle[used] + 180.0) % 360.0 - 180.0
    assert np.max(np.abs(off)) < 1e-3


def test_latched_run_folder_leaves_out_what_the_model_cannot_use(tmp_path: Path) -> None:
    """Clipped samples, a stream restart (sequence back to 0) and the moments the supply
    changed are left out; a latch that does not scale to the table falls back to windows."""
    run = generate(Part(), 6, TINY)
    cpr = 1 << 20
    folder = write_run_folder(tmp_path / "run", run, latched_counts_per_rev=cpr)
    t = np.asarray(run["time_s"])
    with h5py.File(folder / "raw.h5", "a") as f:
        status = f["samples/status"][()]
        status[2000] |= 1 << 1  # SATURATED
        status[2100] |= 1 << 3  # TEMP_INVALID
        f["samples/status"][...] = status
        seq = f["samples/seq"][()]
        seq[3000:] = np.arange(seq.size - 3000)  # STOP/START: the sequence restarts at 0
        f["samples/seq"][...] = seq
    traj = load_data(folder)
    used = np.isin(t, traj.time_s)
    assert not used[2000] and not used[2100] and not used[3000]
    assert used[1999] and used[2001] and used[3001]
    assert any("clipped" in n for n in traj.notes)
    # a supply change logged between two windows (transition 42.3 .. 43.4 s): the engine's
    # readings just before and after bracket it; its moment +/- 0.25 s is left out
    gap = (t > 42.35) & (t < 43.35)
    assert used[gap].all()
    v0 = float(np.median(np.asarray(run["supply_v"])[gap]))
    with h5py.File(folder / "raw.h5", "a") as f:
        g = f["supply"]
        rows = {"station_time_s": [42.80, 42.81, 43.00, 43.01], "voltage_v": [v0, v0 + 0.1,
                                                                              v0 + 0.1, v0],
                "current_a": [0.02] * 4}
        for name, values in rows.items():
            ds = g[name]
            ds.resize((ds.shape[0] + 4,))
            ds[-4:] = np.asarray(values) + (STATION_OFFSET_S if name == "station_time_s" else 0)
    used = np.isin(t, load_data(folder).time_s)
    assert not used[(t > 42.56) & (t < 43.25)].any()
    assert used[(t > 42.35) & (t < 42.5)].all() and used[(t > 43.27) & (t < 43.35)].all()
    with h5py.File(folder / "raw.h5", "a") as f:
        f.attrs["encoder_counts_per_rev"] = 2 * cpr  # the station thinks twice the resolution
    fallback = load_data(folder)
    assert any("does not follow the table" in n for n in fallback.notes)
    assert fallback.n < traj.n  # windows only


def test_run_folder_input_names_the_hidden_effect(tmp_path: Path) -> None:
    run = generate(realistic_part().with_effect("k2_quadratic"), 22, SHORT)
    folder = write_run_folder(tmp_path / "results" / "20260101T000000Z_SYN-0001", run)
    traj = load_data(tmp_path / "results", dut="SYN-0001")
    assert traj.serial == "SYN-0001"
    assert {s.kind for s in traj.segments} <= {"static", "plateau", "stop_static", "stabilise"}
    plateau = [s for s in traj.segments if s.kind == "plateau"]
    assert len(plateau) == 4 * 2 * 4
    res = run_discrepancy(traj, first_order_model())
    assert res.effects_added[:1] == ["k2_quadratic"]
    assert res.gap_final_dps <= 1.5 * res.noise_floor_dps
    with pytest.raises(ValueError, match="not SYN-0002"):
        load_data(folder, dut="SYN-0002")


def test_a_ramps_plateaus_are_read_with_or_without_hardware_sync(tmp_path: Path) -> None:
    """eol-ramp writes its plateaus as `ramp_plateau` (issue 29). Without latched counts they
    are read as the rate table's plateaus (before, they were left out: the record then held
    only the static and stop windows); with them they keep their kind, which a CSV export
    writes and reads back."""
    run = generate(Part(), 5, TINY)
    as_ramp = {**run, "segments": [("ramp_plateau" if k == "plateau" else k, a, b)
                                   for k, a, b in run["segments"]]}  # type: ignore[union-attr]
    plain = load_data(write_run_folder(tmp_path / "rate-table", run))
    ramp = load_data(write_run_folder(tmp_path / "ramp", as_ramp))
    assert ramp.n == plain.n
    assert [s.kind for s in ramp.segments] == [s.kind for s in plain.segments]
    assert "plateau" in {s.kind for s in ramp.segments}
    latched = load_data(write_run_folder(tmp_path / "ramp-sync", as_ramp,
                                         latched_counts_per_rev=1 << 20))
    assert "ramp_plateau" in {s.kind for s in latched.segments}
    csv = tmp_path / "ramp.csv"
    write_csv(csv, latched)
    back = load_data(csv)  # (neighbouring windows of one kind read back as one)
    assert {s.kind for s in back.segments} - {"transition"} == {
        s.kind for s in latched.segments}
    assert back.n == latched.n
