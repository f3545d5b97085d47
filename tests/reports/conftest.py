"""Shared fixtures: synthetic run folders built once per session, poppler helpers."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from reports.certificate import render_certificate
from tests.reports.synth_run import Part, make_run
from tests.tools import need

POPPLER = ("pdftotext", "pdftoppm", "pdfinfo", "pdfimages")


def need_poppler() -> None:
    need(*POPPLER)


def pdf_text(pdf: Path, page: int | None = None, layout: bool = True) -> str:
    need_poppler()
    cmd = ["pdftotext"] + (["-layout"] if layout else [])
    if page is not None:
        cmd += ["-f", str(page), "-l", str(page)]
    return subprocess.run(cmd + [str(pdf), "-"], capture_output=True, text=True,
                          check=True).stdout


def pdf_pages(pdf: Path) -> int:
    need_poppler()
    out = subprocess.run(["pdfinfo", str(pdf)], capture_output=True, text=True,
                         check=True).stdout
    return int(next(line.split()[-1] for line in out.splitlines() if line.startswith("Pages:")))


@pytest.fixture(scope="session")
def runs_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("runs")


@pytest.fixture(scope="session")
def pass_run(runs_root: Path) -> Path:
    folder, record = make_run(runs_root, Part(serial="SIM-PASS-1", bias_dps=3.1, scale=1.021))
    assert record.verdict.value == "PASS"
    render_certificate(folder)
    return folder


@pytest.fixture(scope="session")
def fail_run(runs_root: Path) -> Path:
    folder, record = make_run(runs_root, Part(serial="SIM-FAIL-2", bias_dps=12.5, scale=1.0567,
                                              overdue=True, seed=2))
    assert record.verdict.value == "FAIL" and record.failed_measurements == ["bias_dps"]
    render_certificate(folder)
    return folder


@pytest.fixture(scope="session")
def _pristine_run(runs_root: Path) -> Path:
    folder, _ = make_run(runs_root / "pristine", Part(serial="SIM-DMG-3", seed=3))
    return folder


@pytest.fixture
def fresh_run(tmp_path: Path, _pristine_run: Path) -> Path:
    """A run folder of its own (a copy), for tests that damage it."""
    return Path(shutil.copytree(_pristine_run, tmp_path / _pristine_run.name))
