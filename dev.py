#!/usr/bin/env python3
"""Quick start for a fresh machine with only Python 3.11+.

    python3 dev.py demo    # the station on the simulated bench, ending in a certificate
    python3 dev.py test    # the test suite

Creates ./.venv on first use, installs the station with its test extras into it, and runs
the command there. Extra arguments are passed through (to `station demo` or to pytest).
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
PY = BIN / "python"
STAMP = VENV / ".installed-pyproject-sha256"


def _ensure_env() -> None:
    if sys.version_info < (3, 11):  # noqa: UP036 - this script is what tells an old Python
        sys.exit(f"Python 3.11 or newer is needed; this is {sys.version.split()[0]}.")
    digest = hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    if PY.exists() and STAMP.exists() and STAMP.read_text().strip() == digest:
        return
    if not PY.exists():
        print(f"creating virtual environment in {VENV}", flush=True)
        venv.EnvBuilder(with_pip=True).create(VENV)
    print("installing the station and its dependencies (first run only)", flush=True)
    subprocess.run([str(PY), "-m", "pip", "install", "-q", "--upgrade", "pip"], check=True)
    subprocess.run(
        [str(PY), "-m", "pip", "install", "-q", "-e", f"{ROOT}[test,ui,dev]"], check=True
    )
    STAMP.write_text(digest)


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in {"demo", "test", "station"}:
        print(__doc__)
        return 2
    _ensure_env()
    command, rest = argv[0], argv[1:]
    if command == "test":
        args = [str(PY), "-m", "pytest", *rest]
    elif command == "demo":
        args = [str(BIN / "station"), "demo", *rest]
    else:
        args = [str(BIN / "station"), *rest]
    return subprocess.call(args, cwd=ROOT)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
