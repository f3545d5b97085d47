"""dev.py's first run installs the station editable: quietly (issue 26 (14): setuptools'
"Editable installation" warning about folders named like a package in the working
directory, which are the package here; pyproject.toml says so with package-dir)."""

from __future__ import annotations

import subprocess
import sys
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


def test_the_editable_install_says_no_warning(tmp_path: Path) -> None:
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    py = env_dir / "bin" / "python"
    # as dev.py does (a current pip, then -q -e); without the dependencies, which are not the
    # point here and would take minutes
    steps = [[str(py), "-m", "pip", "install", "-q", "--upgrade", "pip"],
             [str(py), "-m", "pip", "install", "-q", "--no-deps", "-e", str(ROOT)]]
    outputs = []
    for cmd in steps:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path)
        if r.returncode != 0:
            pytest.skip(f"pip could not install here (no package index?): {r.stderr[-300:]}")
        outputs.append(r.stdout + r.stderr)
    said = "\n".join(
        line for line in outputs[1].splitlines() if not line.startswith("WARNING: Location")
    )
    assert "Editable installation" not in said and "Warning" not in said, said
    r = subprocess.run([str(py), "-c", "import station, drivers.sim; print(station.__file__)"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=60)
    assert r.stdout.strip() == str(ROOT / "station" / "__init__.py"), r.stdout + r.stderr
    assert sys.version_info >= (3, 11)
