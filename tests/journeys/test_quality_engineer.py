"""The quality engineer's journey, as README.md and docs/records.md show it, through the
installed `station` command on real run folders of `station run --sim` (issue 26).

Two simulated runs, shared by the module: one of two sockets in lot LOT-7 / work order WO-1
(a good part and one whose bias is beyond the limit: PASS and FAIL) and one part in lot
LOT-8 / WO-2. Then: verify, report, verify again, approve (visible on the certificate; a
FAIL run only with a remark), history by lot and by work order, lot report by lot and by
work order.

The station file is a copy of config/ in a temporary folder (`--station`, `--db`: the
documented options), so the runs, the results database and the station key stay there.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.tools import need

REPO = Path(__file__).resolve().parents[2]
STATION_CMD = Path(sys.executable).parent / "station"  # the installed console script
TWO_PARTS = """\
# two sockets: a population part and one whose bias is beyond gyr130's +/-10 deg/s
parts:
  - {socket: 1, serial: SIM-0001}
  - {socket: 2, serial: SIM-0002, bias_dps: 12.0}
"""


class Bench:
    """A station's working folder: config/ copied, runs/ and the results database in it."""

    def __init__(self, root: Path) -> None:
        self.root = root
        shutil.copytree(REPO / "config", root / "config",
                        ignore=shutil.ignore_patterns("signing"))
        (root / "two-parts.yaml").write_text(TWO_PARTS, encoding="utf-8")
        self.station_file = "config/station.yaml"
        self.db = str(root / "runs" / "results.sqlite")  # station.yaml: ../runs/results.sqlite

    def station(self, *args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
        if not STATION_CMD.exists():
            pytest.skip(f"{STATION_CMD} not installed (python3 dev.py test installs it)")
        out = subprocess.run([str(STATION_CMD), *args], capture_output=True, text=True,
                             cwd=self.root, timeout=timeout)
        assert "Traceback" not in out.stderr, out.stderr
        return out

    def folder(self, serial: str) -> Path:
        (found,) = (self.root / "runs").glob(f"*_{serial}")
        return found


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> Bench:
    b = Bench(tmp_path_factory.mktemp("quality"))
    st = ("--station", b.station_file)
    run = b.station("run", "--sim", "--sim-config", "two-parts.yaml", "--dut", "1=SIM-0001",
                    "--dut", "2=SIM-0002", "--lot", "LOT-7", "--work-order", "WO-1", *st)
    assert run.returncode == 1, run.stdout + run.stderr  # 1: a part FAILed
    assert "socket 1 SIM-0001: PASS" in run.stdout and "socket 2 SIM-0002: FAIL" in run.stdout
    run = b.station("run", "--sim", "--dut", "SIM-0003", "--lot", "LOT-8", "--work-order",
                    "WO-2", *st)
    assert run.returncode == 0, run.stdout + run.stderr
    return b


def pdftotext(pdf: Path, layout: bool = True) -> str:
    need("pdftotext")
    cmd = ["pdftotext", *(["-layout"] if layout else []), str(pdf), "-"]
    return subprocess.run(cmd, capture_output=True, text=True, check=True).stdout


def test_verify_then_report_then_verify(bench: Bench) -> None:
    folder = bench.folder("SIM-0001")
    out = bench.station("verify", str(folder), "--station", bench.station_file)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "intact" in out.stdout and "sealed at the end of the run" in out.stdout
    out = bench.station("report", str(folder), "--station", bench.station_file)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == str(folder / "certificate.pdf")
    out = bench.station("verify", str(folder), "--station", bench.station_file)
    assert out.returncode == 0 and "not at the run" not in out.stdout  # finding 10
    assert "sealed at the end of the run, sealed again by `station report`" in out.stdout


def test_approve_shows_on_the_certificate(bench: Bench) -> None:
    folder = bench.folder("SIM-0001")
    out = bench.station("approve", str(folder), "--by", "Quinn Quality",
                        "--station", bench.station_file)
    assert out.returncode == 0, out.stderr
    text = pdftotext(folder / "certificate.pdf")
    box = text[text.rindex("Reviewed by (quality)"):]
    assert "Quinn Quality (quality)" in box and "Approval-1" in box  # finding 9
    need("pdfsig")
    sig = subprocess.run(["pdfsig", str(folder / "certificate.pdf")],
                         capture_output=True, text=True).stdout
    assert sig.count("Signature is Valid.") == 2, sig
    assert bench.station("verify", str(folder), "--station", bench.station_file).returncode == 0


def test_a_fail_run_needs_a_remark(bench: Bench) -> None:
    folder = bench.folder("SIM-0002")
    out = bench.station("approve", str(folder), "--by", "Quinn Quality",
                        "--station", bench.station_file)
    assert out.returncode == 2 and out.stderr.count("\n") == 1 and "--remark" in out.stderr
    out = bench.station("approve", str(folder), "--by", "Quinn Quality", "--remark",
                        "bias beyond limit: part scrapped, approved as a record",
                        "--station", bench.station_file)
    assert out.returncode == 0, out.stderr
    text = " ".join(pdftotext(folder / "certificate.pdf", layout=False).split())
    assert "Quinn Quality (quality); remark: bias beyond limit" in text


@pytest.mark.parametrize("flag, value, serials", [
    ("--lot", "LOT-7", {"SIM-0001", "SIM-0002"}),
    ("--work-order", "WO-2", {"SIM-0003"}),
])
def test_history_by_lot_and_work_order(bench: Bench, flag: str, value: str,
                                       serials: set[str]) -> None:
    out = bench.station("history", flag, value, "--db", bench.db)
    assert out.returncode == 0, out.stderr  # finding 5: was an unrecognized argument
    shown = set(re.findall(r"SIM-000\d", out.stdout))
    assert shown == serials, out.stdout
    assert f"{len(serials)} run{'s' if len(serials) > 1 else ''}:" in out.stdout


@pytest.mark.parametrize("flag, value, runs", [("--lot", "LOT-7", 2), ("--work-order", "WO-2", 1)])
def test_lot_report_by_lot_and_work_order(bench: Bench, flag: str, value: str,
                                          runs: int) -> None:
    pdf = bench.root / f"{value}.pdf"
    out = bench.station("lot-report", flag, value, "--db", bench.db, "--out", str(pdf),
                        "--include-simulated")  # the bench simulates its parts
    assert out.returncode == 0, out.stderr
    assert pdf.read_bytes().startswith(b"%PDF")
    assert f"{runs} run{'s' if runs > 1 else ''}, yield" in out.stdout
    text = pdftotext(pdf)
    assert f"{flag.removeprefix('--').replace('-', '_')} = {value}" in text
    assert "deg/sqrt(h)" in text.split()  # units whole in the capability table (finding 14)
