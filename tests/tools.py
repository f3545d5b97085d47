"""The Debian tools some tests run (poppler-utils, mbpoll, socat, openssl, chromium).

A test asks for one with `need`: on a developer's machine without it the test is skipped
with the reason; under `.ci/run`, which installs them all and sets
STATION_TEST_TOOLS=required, a missing tool fails the test, so no check goes missing
silently (a test that quietly did less with `if shutil.which(...)` hid six PDF checks).
"""

from __future__ import annotations

import os
import shutil

import pytest

PACKAGES = {"pdftotext": "poppler-utils", "pdftoppm": "poppler-utils",
            "pdfinfo": "poppler-utils", "pdfimages": "poppler-utils", "pdfsig": "poppler-utils",
            "mbpoll": "mbpoll", "socat": "socat", "openssl": "openssl",
            "chromium": "chromium", "psql": "postgresql", "initdb": "postgresql"}


def required() -> bool:
    """True where a missing tool is a failure (CI), not a reason to skip."""
    return os.environ.get("STATION_TEST_TOOLS") == "required"


def missing(reason: str) -> None:
    """Skip the calling test for `reason`, or fail it where the tools are required."""
    if required():
        pytest.fail(f"{reason}; STATION_TEST_TOOLS=required (.ci/run installs every tool)")
    pytest.skip(reason)


def need(*tools: str) -> str:
    """The path of the first tool; skips (or fails in CI) when any is not installed."""
    absent = [t for t in tools if shutil.which(t) is None]
    if absent:
        packages = sorted({PACKAGES.get(t, t) for t in absent})
        missing(f"{', '.join(absent)} not installed (apt-get install {' '.join(packages)}; "
                ".ci/run does)")
    return str(shutil.which(tools[0]))
