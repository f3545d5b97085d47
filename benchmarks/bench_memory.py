"""Peak memory of the station through the full procedure, eight sockets at 1 kHz.

Runs the station in this process on a simulated bench in lockstep (its own process, not
counted) with the procedure's output rate raised to `--rate-hz` and the fixture's baud to
carry it, and prints the station's peak resident memory (ru_maxrss), its resident memory
sampled through the run (it should stay flat: samples stream to raw.h5 and the steps read
older windows back), the samples taken and the station and wall time.

    python3 benchmarks/bench_memory.py [--sockets 8] [--rate-hz 1000] [--procedure FILE]
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.fixture_protocol import sample_stream_baud  # noqa: E402
from procedures.runtime.record import read_record  # noqa: E402
from station.settings import LoadedSettings  # noqa: E402
from station.sim_run import run_simulated  # noqa: E402
from station.station_file import load_settings  # noqa: E402


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


def procedure_at(path: Path, rate_hz: int, folder: Path) -> Path:
    """A copy of the procedure at `rate_hz` (its product path made absolute)."""
    data: dict[str, Any] = yaml.safe_load(path.read_text(encoding="utf-8"))
    if isinstance(data.get("power"), dict) and "output_rate_hz" in data["power"]:
        data["power"]["output_rate_hz"] = rate_hz  # the section form
    else:
        data["output_rate_hz"] = rate_hz  # the step-list form
    data["product"] = str((path.parent / data["product"]).resolve())
    out = folder / f"{path.stem}-{rate_hz}hz.yaml"
    out.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return out


def settings_for(rate_hz: int) -> LoadedSettings:
    """The installation's station.yaml with the fixture's baud raised to carry `rate_hz`."""
    loaded = load_settings()
    s = loaded.settings
    baud = max(s.instruments.fixture.baud, 2 * sample_stream_baud(rate_hz))
    fixture = s.instruments.fixture.model_copy(update={"baud": baud})
    instruments = s.instruments.model_copy(update={"fixture": fixture})
    return LoadedSettings(settings=s.model_copy(update={"instruments": instruments}),
                          source=loaded.source)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sockets", type=int, default=8)
    ap.add_argument("--rate-hz", type=int, default=1000)
    ap.add_argument("--procedure", default=str(ROOT / "config/procedures/eol-rate-table.yaml"))
    args = ap.parse_args()
    out = Path(tempfile.mkdtemp(prefix="bench-memory-"))
    proc = procedure_at(Path(args.procedure), args.rate_hz, out)
    parts = [{"socket": s, "serial": f"SIM-{7500 + s:04d}"} for s in range(1, args.sockets + 1)]
    samples: list[tuple[float, float]] = []
    done = threading.Event()

    def sample_rss() -> None:
        t0 = time.monotonic()
        while not done.wait(0.5):
            samples.append((time.monotonic() - t0, rss_mb()))

    sampler = threading.Thread(target=sample_rss, daemon=True)
    before_mb = rss_mb()
    w0 = time.monotonic()
    sampler.start()
    result, _ = run_simulated(
        parts, procedure_path=proc, out=out / "runs", settings=settings_for(args.rate_hz)
    )
    done.set()
    wall_s = time.monotonic() - w0
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    recs = [read_record(result.folders[s]) for s in sorted(result.folders)]
    n_samples = sum(
        int(Path(result.folders[s] / "raw.h5").stat().st_size) for s in sorted(result.folders)
    )
    verdicts = ",".join(str(r.verdict) for r in recs)
    print(f"procedure {Path(args.procedure).name} at {args.rate_hz} Hz, {args.sockets} sockets, "
          "bench in lockstep")
    print(f"station time {result.station_time_s / 60:.1f} min, wall {wall_s:.0f} s, "
          f"verdicts {verdicts}")
    print(f"raw.h5 written: {n_samples / 2**20:.0f} MiB in all")
    quarter = max(len(samples) // 4, 1)
    for i in range(0, len(samples), quarter):
        print(f"  RSS at {samples[i][0]:6.0f} s wall: {samples[i][1]:7.0f} MB")
    print(f"RSS before the run {before_mb:.0f} MB; peak RSS of the station {peak_mb:.0f} MB "
          "(target 400 MB)")
    print(f"run folders in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
