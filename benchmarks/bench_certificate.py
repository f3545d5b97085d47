"""Time to render, sign and seal one certificate, and to verify a run folder.

    python3 benchmarks/bench_certificate.py [--run-folder PATH] [--repeat 5]

Without --run-folder a realistic synthetic run folder (4 conditions, ~30k samples) is built
in a temporary folder, with a station file, key and certificate of its own there. Reports
each stage's median and worst: render (reportlab), the station's PAdES signature (pyHanko),
an approval's second signature, the manifest (hashes + RSA signature) and `verify`.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from reports.certificate import certificate_bytes  # noqa: E402
from station.certify import signed_certificate, station_identity  # noqa: E402
from station.manifest import seal, verify_folder  # noqa: E402
from station.pdf_signing import sign_pdf_bytes  # noqa: E402
from station.station_file import load_settings  # noqa: E402
from tests.reports.synth_run import Part, make_run  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def timed(fn: Callable[[], object], repeat: int) -> tuple[float, float, object]:
    times, result = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), max(times), result


def line(label: str, med: float, worst: float) -> None:
    print(f"{label:<34} median {med * 1000:8.1f} ms   worst {worst * 1000:8.1f} ms")


def main() -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--run-folder", type=Path, help="a real run folder (copied, not changed)")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        station_yaml = root / "station.yaml"
        station_yaml.write_text((REPO / "config" / "station.yaml").read_text().replace(
            "procedure: procedures/", f"procedure: {REPO}/config/procedures/"))
        settings = load_settings(station_yaml)
        t0 = time.perf_counter()
        identity = station_identity(settings)
        print(f"{'station key + certificate made':<34} {(time.perf_counter() - t0) * 1000:8.1f} ms"
              " (first use only)")
        if args.run_folder is not None:
            folder = Path(shutil.copytree(args.run_folder, root / args.run_folder.name))
        else:
            folder, _ = make_run(root / "runs", Part(serial="BENCH-1", bias_dps=12.5))
        med, worst, pdf = timed(lambda: certificate_bytes(folder), args.repeat)
        assert isinstance(pdf, bytes)
        line("render (reportlab)", med, worst)
        sid = settings.settings.station.id
        med, worst, signed = timed(lambda: signed_certificate(pdf, identity, sid, "X", []),
                                   args.repeat)
        assert isinstance(signed, bytes)
        line("station signature (pyHanko)", med, worst)
        med, worst, _ = timed(lambda: sign_pdf_bytes(signed, identity, field_name="Approval-1",
                                                     reason="bench", signer_name="bench"),
                              args.repeat)
        line("approval signature (incremental)", med, worst)
        (folder / "certificate.pdf").write_bytes(signed)
        med, worst, _ = timed(lambda: seal(folder, identity, "run"), args.repeat)
        line("manifest (hash + sign)", med, worst)
        med, worst, result = timed(lambda: verify_folder(folder, {identity.fingerprint}),
                                   args.repeat)
        assert getattr(result, "intact", False)
        line("verify", med, worst)
        raw_mib = (folder / "raw.h5").stat().st_size / 2**20
        print(f"certificate {len(signed) / 1024:.0f} KiB signed, raw.h5 {raw_mib:.1f} MiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
