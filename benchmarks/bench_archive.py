"""Retention: what `station archive` makes of a real run folder, and how long it takes.

    python3 benchmarks/bench_archive.py [--run-folder PATH] [--repeat 3]

Without --run-folder one part is run on the simulated bench (`station run --sim`, the shipped
procedure) into a temporary folder. Prints the folder's and the archive's size, then per
repeat the wall time to archive it (write, fsync, verify, remove), to verify the archive
(`station verify`'s check) and to read its certificate out of it (the dashboard's way).
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from procedures.runtime.record import CERTIFICATE_FILE  # noqa: E402
from station.retention import archive_folder  # noqa: E402
from station.run_archive import read_member, verify_archive  # noqa: E402


def _size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def _station_run(out: Path) -> Path:
    done = subprocess.run([sys.executable, "-m", "station", "run", "--sim", "--dut", "SIM-0001",
                           "--out", str(out)], cwd=ROOT, capture_output=True, text=True)
    if done.returncode not in (0, 1):  # PASS or FAIL: a finished, sealed run folder
        raise SystemExit(f"station run --sim failed:\n{done.stdout}{done.stderr}")
    return next(out.glob("*_SIM-0001"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run-folder", type=Path)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-archive-") as tmp:
        work = Path(tmp)
        source = args.run_folder or _station_run(work / "runs")
        times: dict[str, list[float]] = {"archive": [], "verify": [], "certificate": []}
        for i in range(args.repeat):
            folder = work / f"copy{i}" / source.name
            shutil.copytree(source, folder)
            out = work / f"archive{i}"
            out.mkdir()
            t0 = time.perf_counter()
            target = archive_folder(folder, out, None, None)
            t1 = time.perf_counter()
            status = verify_archive(target).status
            t2 = time.perf_counter()
            pdf = read_member(target, source.name, CERTIFICATE_FILE, 64 * 2**20)
            t3 = time.perf_counter()
            assert pdf and not folder.exists(), (status, folder)
            for key, dt in zip(times, (t1 - t0, t2 - t1, t3 - t2), strict=True):
                times[key].append(dt)
        folder_b, archive_b = _size(source), target.stat().st_size
        print(f"run folder {folder_b / 1e6:.2f} MB -> archive {archive_b / 1e6:.2f} MB "
              f"({100 * archive_b / folder_b:.1f} %), verify: {status.name}")
        for key, values in times.items():
            print(f"{key:12s} median {statistics.median(values):.3f} s  "
                  f"max {max(values):.3f} s  ({len(values)} repeats)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
