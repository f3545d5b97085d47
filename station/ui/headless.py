"""Debian's chromium driven by Playwright, for browser tests, screenshots and benchmarks.

Playwright's own browser download is not used (there is no network on the line): the
system's chromium is launched by path. Playwright is a test/tooling dependency only.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

CHROMIUM_PATH = os.environ.get("STATION_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def chromium_missing_reason() -> str | None:
    """Why the browser cannot run here, or None when it can."""
    if not os.path.exists(CHROMIUM_PATH):
        return f"{CHROMIUM_PATH} not found: install Debian's chromium (.ci/run does)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the playwright Python package is missing: pip install playwright"
    return None


@contextmanager
def chromium() -> Iterator[Any]:
    """A headless chromium Browser (Playwright), closed on exit."""
    reason = chromium_missing_reason()
    if reason:
        raise RuntimeError(reason)
    # playwright (test extra): only for a headless browser
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM_PATH, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()


def wait_js(page: Any, expression: str, timeout_s: float = 30.0, poll_s: float = 0.01) -> Any:
    """Poll `expression` in the page until it is truthy; returns its value.

    Playwright's wait_for_function compiles its predicate inside the page, which the pages'
    Content-Security-Policy (no eval) forbids; page.evaluate is not subject to it.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        value = page.evaluate(expression)
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"{expression!r} still false after {timeout_s:g} s")
        time.sleep(poll_s)
