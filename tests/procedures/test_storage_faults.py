"""A disk that refuses a write (full, read-only, failing) during a run, in process: the run
ends ERROR naming the file, the safe state is done, the record is kept (in its folder, or the
fallback folder), and raw.h5 never takes the process down (docs/safety.md)."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import procedures.runtime.rawdata as rawdata
import procedures.runtime.record as record_module
from procedures.engine.engine import Engine
from procedures.runtime.rawdata import RawDataWriter, read_raw
from procedures.runtime.record import StorageError, Verdict, read_record, storage_error
from procedures.runtime.run_context import RunContext
from tests.procedures.test_engine_mechanics import SAFE_START_AND_END, Scripted, _ctx

ROOT = Path(__file__).resolve().parents[2]


def test_an_os_error_in_a_step_is_an_error_naming_the_file(tmp_path: Path) -> None:
    ctx, calls = _ctx(tmp_path)
    target = tmp_path / "no-such-folder" / "export.csv"

    def write(ctx: RunContext, n: int) -> None:
        target.write_text("x")  # FileNotFoundError naming the file

    verdicts = Engine(ctx, [Scripted(name="export", action=write)]).run()  # type: ignore[arg-type]
    assert verdicts == {1: Verdict.ERROR}
    assert calls == SAFE_START_AND_END
    reason = read_record(tmp_path / "p1").reason
    assert "internal error" not in reason
    assert str(target) in reason and "in step export" in reason


def test_raw_data_the_disk_refuses_ends_the_run_error_naming_raw_h5(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ctx, calls = _ctx(tmp_path)
    part = ctx.parts[0]
    part.folder.mkdir()
    part.writer = RawDataWriter(part.folder / "raw.h5", {"serial": part.serial})
    part.rows.writer = part.writer

    def log_rows(ctx: RunContext, n: int) -> None:
        ctx.records.event("a row for raw.h5")
        part.rows.flush()
        # the disk fills after the first step's rows: _room_for refuses the next write
        monkeypatch.setattr(rawdata, "RESERVE_BYTES", 1 << 62)

    steps = [Scripted(name="first", action=log_rows), Scripted(name="second", action=log_rows),
             Scripted(name="third")]
    verdicts = Engine(ctx, steps).run()  # type: ignore[arg-type]
    assert verdicts == {1: Verdict.ERROR}
    assert calls == SAFE_START_AND_END  # the safe state was done, at the start and the end
    rec = read_record(part.folder)
    raw = part.folder / "raw.h5"
    assert f"cannot write {raw}: No space left on device" in rec.reason
    # the run stopped at its first check after the failure (a Scripted step sleeps 1 s)
    assert "(in step third)" in rec.reason and rec.timings["third"] < 1.0
    assert (rec.analysis.safe_state or {}).get("supply") == "safe"
    # refused before HDF5 failed: the file was closed cleanly and keeps the first step's rows
    kept = read_raw(raw)["events"]["text"]
    assert "a row for raw.h5" in list(kept)


def test_a_record_whose_folder_cannot_be_written_goes_to_the_fallback_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fallback = tmp_path / "fallback"
    monkeypatch.setattr(record_module, "FALLBACK_FOLDER", fallback)
    ctx, calls = _ctx(tmp_path)
    part = ctx.parts[0]

    def folder_goes(ctx: RunContext, n: int) -> None:
        part.folder.rename(tmp_path / "moved")
        part.folder.write_text("not a folder")  # record.json can no longer be written there

    verdicts = Engine(ctx, [Scripted(name="a", action=folder_goes)]).run()  # type: ignore[arg-type]
    assert verdicts == {1: Verdict.ERROR}
    assert calls == SAFE_START_AND_END
    kept = fallback / "r1.json"
    assert part.kept is not None and part.kept.path == kept
    rec = record_module.RunRecord.model_validate_json(kept.read_text())
    assert rec.verdict is Verdict.ERROR and "record.json" in rec.reason


def test_storage_error_names_the_file_and_reads_errno_from_hdf5_text() -> None:
    err = storage_error("/runs/x/raw.h5", RuntimeError(
        "Unable to flush file (file write failed: time = ..., errno = 28, error message = "
        "'No space left on device')"))
    assert isinstance(err, OSError) and err.errno == errno.ENOSPC
    assert str(err) == "cannot write /runs/x/raw.h5: No space left on device"
    ro = storage_error("/runs/x/record.json", OSError(errno.EROFS, "Read-only file system"))
    assert str(ro) == "cannot write /runs/x/record.json: Read-only file system"


# a raw.h5 on a small tmpfs, written until the disk itself refuses (no reserve): HDF5's own
# write fails, and before the fix the process died at exit with SIGSEGV (exit 139)
_FILL = textwrap.dedent("""
    import sys
    from pathlib import Path
    import numpy as np
    import procedures.runtime.rawdata as rawdata
    from procedures.runtime.record import StorageError
    rawdata.RESERVE_BYTES = 0
    w = rawdata.RawDataWriter(Path(sys.argv[1]), {"serial": "X"})
    n = 0
    try:
        while True:
            t = np.arange(n, n + 4096, dtype=float)
            z = np.zeros(4096)
            w.append("samples", time_s=t, seq=t.astype(int), rate_code=z.astype(int),
                     temp_code=z.astype(int), status=z.astype(int), rate_dps=z, temp_c=z,
                     station_time_s=t, encoder_counts=z.astype(int))
            n += 4096
    except StorageError as exc:
        print("FAILED", exc)
    try:
        w.close()
    except StorageError as exc:
        print("CLOSE", exc)
    print("ROWS", n)
""")


@pytest.fixture
def small_tmpfs(tmp_path: Path):  # type: ignore[no-untyped-def]
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def test_raw_h5_on_a_disk_that_refuses_never_crashes_the_process(small_tmpfs: Path) -> None:
    path = small_tmpfs / "raw.h5"
    r = subprocess.run([sys.executable, "-c", _FILL, str(path)], capture_output=True, text=True,
                       cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=120)
    assert r.returncode == 0, (r.returncode, r.stderr[-2000:])
    assert f"FAILED cannot write {path}: No space left on device" in r.stdout
    assert f"CLOSE cannot write {path}" in r.stdout  # close says so again, and returns
    assert int(r.stdout.split("ROWS ")[1]) > 0


def test_a_failed_writer_refuses_every_later_call(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    w = RawDataWriter(tmp_path / "raw.h5", {"serial": "X"})
    monkeypatch.setattr(rawdata, "RESERVE_BYTES", 1 << 62)
    with pytest.raises(StorageError):
        w.append("events", station_time_s=np.array([1.0]), text=["x"])
    assert w.failure is not None
    for call in (lambda: w.append("events", station_time_s=[2.0], text=["y"]),
                 lambda: w.read_rows("events", 0, 1), w.close):
        with pytest.raises(StorageError) as info:
            call()
        assert info.value is w.failure


def test_a_huge_record_json_is_refused_without_reading_it(tmp_path: Path) -> None:
    import time

    with (tmp_path / "record.json").open("wb") as fh:
        fh.truncate(4 * 1024**3)  # sparse 4 GB
    t0 = time.monotonic()
    with pytest.raises(ValueError, match="larger than 64 MB"):
        read_record(tmp_path)
    assert time.monotonic() - t0 < 5.0
